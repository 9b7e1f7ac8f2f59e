"""Device commands in the measured-data format (``device_commands.csv``) and their replay in re-simulation.

fishfmu's run of a line with a reject gate logs every change of the gate's command; ``compare`` replays that log,
so the re-simulation's rejections are physics, not a gate that never fires (issue 39, item 5).  Without the log,
compare says what it cannot replay and leaves it out; calibrate and diagnose refuse (exit 2).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.contract.device_commands import command_schedule
from plant.contract.measured import read_dataset
from plant.errors import InputError
from plant.sim.observers import StepInputs
from plant.sim.recorder import RunRecorder
from plant.sim.state import PlantOutputs, PlantState

from tests.test_bad_input import assert_one_clear_line, run_main, sandbox  # noqa: F401 (a fixture, used by name)

ROOT = Path(__file__).resolve().parents[1]
RD = ROOT / "scenarios" / "reject_doubles.toml"
CUT = {"fish.count": 8, "run.duration_s": 40.0}  # seed 1: two fish of a double rejected, in 9 s on one core


@pytest.fixture(scope="module")
def rd_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """reject_doubles cut down, run by fishfmu: its folder."""
    from fishfmu import commands
    out = tmp_path_factory.mktemp("rd") / "rd"
    commands.run(RD, out, dict(CUT), report=False)
    return out


@pytest.fixture(scope="module")
def without_log(rd_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same dataset with its device_commands.csv removed (a line that logged only its rejections)."""
    ds = tmp_path_factory.mktemp("nolog") / "ds"
    shutil.copytree(rd_run / "run", ds)
    for f in ds.glob("runs/*/device_commands.csv"):
        f.unlink()
    return ds


def _log(rd_run: Path) -> pd.DataFrame:
    return pd.read_csv(next((rd_run / "run").glob("runs/*/device_commands.csv")))


def test_a_run_logs_every_change_of_its_devices_commands(rd_run: Path):
    """The log against the controller's reject output in signals.csv (recorded at each step's end: a change seen
    at t + dt was commanded for the step starting at t)."""
    log = _log(rd_run)
    signals = pd.read_csv(rd_run / "signals.csv")
    reject = signals["controller.reject"].astype(bool).to_numpy()
    t_end = signals["t_s"].to_numpy(float)
    changed = np.flatnonzero(np.diff(np.concatenate([[False], reject])))
    assert list(log["device_id"]) == ["gate"] * (len(changed) + 1)
    assert log["t_s"].iloc[0] == 0.0 and log["command"].iloc[0] == 0  # every device's command at the start
    np.testing.assert_allclose(log["t_s"].iloc[1:], t_end[changed] - 0.01, atol=1e-9)
    assert list(log["command"].iloc[1:]) == [int(reject[k]) for k in changed]
    assert len(changed) >= 2  # the gate fired in this run (else the tests below prove nothing)


def test_compare_replays_the_logged_commands(rd_run: Path, tmp_path: Path):
    """Same model, same commands: the re-simulation rejects the same fish, and as many doubles reach the outfeed."""
    from fishfmu import commands
    done = commands.compare(rd_run / "run", tmp_path / "c", workers=1)
    kpis = done.comparison.kpis.set_index("kpi")
    measured = json.loads((rd_run / "kpis.json").read_text())
    assert measured["rejected"] >= 1
    for k in ("rejected", "doubles_out", "singulated", "lost"):
        assert kpis.loc[k, "simulated"] == kpis.loc[k, "measured"] == measured[k], k
    sim_rejections = pd.read_csv(next((tmp_path / "c" / "simulated").glob("runs/*/rejections.csv")))
    run_rejections = pd.read_csv(next((rd_run / "run").glob("runs/*/rejections.csv")))
    assert sorted(sim_rejections["fish_id"]) == sorted(run_rejections["fish_id"])
    assert not done.comparison.not_replayed
    assert json.loads((tmp_path / "c" / "compare.json").read_text())["not_replayed"] == {}


def test_given_what_a_dataset_does_not_carry_the_replay_is_bit_identical(rd_run: Path):
    """The replay of the command log is exact: with the two inputs a re-simulation of a dataset lacks (the side each
    fish lies on, drawn by the scenario's seed; each step's belt speed, which the drive log stamps with the step's
    end), the plant driven by device_commands.csv gives the run's tracks, beams and rejections bit for bit.  A command
    replayed one step early or late moves the gate 10 ms off and shows in the tracks."""
    from fishfmu.cosim.build import scenario_fish
    from fishfmu.scenario import schema
    from plant.sim.simulate import simulate_plant
    ds = read_dataset(rd_run / "run")
    run = ds.runs[0]
    sc = schema.load_scenario(rd_run / "scenario.resolved.toml")
    by_step = {int(round(t / 0.01)): dict(zip(g["conveyor_id"], g["speed_mps"])) for t, g in run.belts.groupby("t_s")}
    sim = simulate_plant(ds.line, scenario_fish(sc), lambda t: by_step[int(round(t / 0.01)) + 1], 40.0,
                         params=sc.plant, device_commands=command_schedule(run.device_commands, ("gate",)))
    assert len(run.rejections) >= 1
    for measured, simulated in ((run.tracks, sim.tracks), (run.photoeyes, sim.photoeyes),
                                (run.rejections, sim.rejections)):
        pd.testing.assert_frame_equal(simulated.reset_index(drop=True), measured.reset_index(drop=True),
                                      check_exact=True, check_dtype=False)
    pd.testing.assert_frame_equal(sim.device_commands, run.device_commands, check_exact=True, check_dtype=False)


def test_without_the_command_log_compare_says_what_it_cannot_replay(rd_run: Path, without_log: Path, tmp_path: Path):
    from fishfmu import commands
    done = commands.compare(without_log, tmp_path / "c", workers=1)
    doc = json.loads((tmp_path / "c" / "compare.json").read_text())
    (run_id, entry), = doc["not_replayed"].items()
    assert "device_commands.csv" in entry["reason"] and "'gate'" in entry["reason"]
    assert {"rejected", "doubles_out", "singulated"} <= set(entry["kpis_not_compared"])
    assert entry["arrivals_and_tracks_from_x_m"] == 6.53  # the gate's hinge
    kpis = pd.read_csv(tmp_path / "c" / "kpis.csv").set_index("kpi")
    for k in ("rejected", "doubles_out"):  # measured kept, no simulated value and no error: not model error
        assert kpis.loc[k, "measured"] == json.loads((rd_run / "kpis.json").read_text())[k]
        assert np.isnan(kpis.loc[k, "simulated"]) and np.isnan(kpis.loc[k, "error"])
        assert kpis.loc[k, "note"].startswith("not compared")
    assert "singulation_rate error" not in set(done.comparison.measures["measure"])
    arrivals = done.comparison.arrivals
    assert arrivals.loc[arrivals["sensor_id"] == "pe_c5", "error_s"].isna().all()  # after the gate
    assert arrivals.loc[arrivals["sensor_id"] == "pe_c1", "error_s"].notna().any()  # before it: compared
    assert "Not replayed" in (tmp_path / "c" / "report.html").read_text()


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_calibrate_and_diagnose_refuse_a_run_whose_devices_they_cannot_fire(without_log: Path, sandbox: Path,
                                                                           capsys, monkeypatch, command: str):
    code, err = run_main(sandbox, capsys, monkeypatch, command, str(without_log), "--out", "o")
    assert_one_clear_line(code, err, f"{command} refuses", "device_commands.csv", "'gate'")


def _with_log(rd_run: Path, tmp_path: Path, text: str) -> Path:
    ds = tmp_path / "ds"
    shutil.copytree(rd_run / "run", ds)
    next(ds.glob("runs/*/device_commands.csv")).write_text(text)
    return ds


BAD_LOGS = [
    ("t_s,device_id,command\n0,gate,0\n17.8,gate,0.5\n", "row 3, column command", "Boolean"),
    ("t_s,device_id,command\n0,gate,0\n17.8,flap,1\n", "row 3, column device_id", "unknown device_id 'flap'"),
    ("t_s,device_id,command\n0,gate,0\n17.8,gate,1\n17.5,gate,0\n", "row 4, column t_s", "time order"),
    ("t_s,device_id,command\n0,gate,0\n900,gate,1\n", "row 3, column t_s", "after the end of the drive log"),
    ("t_s,device_id,command\n-1,gate,0\n", "row 2, column t_s", "before the run's start"),
    ("t_s,device_id,command\n0,gate,0\n0,gate,1\n", "row 3, column t_s", "twice"),
    ("t_s,device_id,command\n", "device_commands.csv", "device 'gate' of the line has no row"),
    ("t_s,device_id\n0,gate\n", "line 1 (header)", "missing required column command"),
]


@pytest.mark.parametrize("text,where,what", BAD_LOGS)
def test_a_bad_device_command_log_is_refused_naming_its_row(rd_run: Path, tmp_path: Path, text: str, where: str,
                                                           what: str):
    ds = _with_log(rd_run, tmp_path, text)
    with pytest.raises(InputError) as err:
        read_dataset(ds)
    assert where in str(err.value) and what in str(err.value) and "device_commands.csv" in str(err.value)


def test_the_command_line_exits_2_naming_the_bad_row(rd_run: Path, sandbox: Path, capsys, monkeypatch):
    ds = _with_log(rd_run, sandbox / "tmp", "t_s,device_id,command\n0,gate,0\n17.8,gate,2\n")
    code, err = run_main(sandbox, capsys, monkeypatch, "compare", str(ds), "--out", "o")
    assert_one_clear_line(code, err, "device_commands.csv", "row 3, column command", "command = 2")


def test_a_command_acts_from_the_first_step_starting_at_or_after_it():
    """A PLC's output logged between two step starts is taken at the next one, as a served line takes it."""
    log = pd.DataFrame({"t_s": [0.0, 0.013, 0.05], "device_id": ["a", "a", "a"], "command": [0.0, 1.0, 0.0]})
    at = command_schedule(log, ("a", "b"))
    steps = [round(0.01 * k, 2) for k in range(7)]
    assert [at(t)["a"] for t in steps] == [False, False, True, True, True, False, False]
    assert not any(at(t)["b"] for t in steps)  # a device with no row: home


def test_the_recorder_logs_changes_at_the_steps_start_and_nothing_without_devices():
    rec = RunRecorder([], ["c1"], [], 0.01, ("g",))
    for k, on in enumerate([False, True, True, False], start=1):
        rec.record(empty_line_state(0.01 * k), StepInputs({"c1": 0.0}, {"g": on}, {"c1": 0.0}))
    log = rec.tables()["device_commands"]
    assert list(log.itertuples(index=False, name=None)) == [(0.0, "g", 0), (0.01, "g", 1), (0.03, "g", 0)]
    assert RunRecorder([], ["c1"], [], 0.01).tables()["device_commands"] is None


def empty_line_state(t_s: float) -> PlantState:
    """A line without fish after a step ending at ``t_s``, its one belt still, its device home."""
    none = np.zeros(0, dtype=np.int64)
    return PlantState(t_s, (), np.zeros(0, dtype=np.int8), none, none, np.zeros((0, 3)), np.zeros((0, 3, 3)),
                      np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(3),
                      outputs=PlantOutputs(t_s, {"c1": 0.0}, {"c1": 0.0}, {"c1": 0.0}, {}),
                      rejected_by=np.zeros(0, dtype=np.int64), device_position=np.zeros(1))
