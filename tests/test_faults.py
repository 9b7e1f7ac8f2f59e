"""Faults while running: an FMU that fails, hangs or crashes, a plant that blows up, a run that is
interrupted.  Each stops the run with a message naming the FMU or fish, the time and what happened,
and keeps what was recorded until then; a crashing or hanging FMU in a worker process does not take
the orchestrator (here: the test process) down with it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

from plant.errors import SimulationError
from plant.sim.health import EnergyWatch, spring_reserve_j
from plant.contract.measured import read_dataset
from plant.sim.plant import Plant
from tests.plant_helpers import fish, straight_line

from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
FAULT_T = 0.5
FAULTS = {1: 'doStep returned error: "faulty_drive: failing on purpose at t = 0.5 s"',
          2: 'doStep returned fatal: "faulty_drive: fatal failure on purpose at t = 0.5 s"',
          3: "doStep did not return within 1 s (hung); its worker process was killed",
          4: "its worker process died during doStep (killed by signal SIGSEGV)",
          5: "output 'belt_speed' is nan"}


def faulty_overrides(fmu: Path, fault: int, process: str) -> dict:
    """The paper line with its infeed driven by the faulty FMU alone (the other belts at constant speed)."""
    return {
        "fmu": [{"name": "drive_c1", "path": str(fmu), "parameters": {"fault": fault, "fault_time": FAULT_T}}],
        "wiring.connections": ["drive_c1.belt_speed -> plant.c1.speed", "plant.c1.load_force -> drive_c1.load_force"],
        "wiring.inputs": {"drive_c1.speed_setpoint": 0.25, "plant.c2.speed": 0.5, "plant.c3.speed": 0.8,
                          "plant.c4.speed": 1.25},
        "run.duration_s": 1.0, "fish.count": 1, "fish.first_drop_s": 0.0, "run.stop_when_clear": False,
        "run.fmu_process": process, "run.fmu_step_timeout_s": 1.0, "expect": {}}


def assert_stopped_at_the_fault(result, fault: int) -> None:
    assert result.status == "failed"
    assert result.error == f"at t = {FAULT_T + (0.01 if fault == 5 else 0.0):.3f} s: FMU 'drive_c1': {FAULTS[fault]}"
    # everything up to the failing step is kept: signals, tracks of the fish dropped at t = 0
    assert result.t_end_s == pytest.approx(FAULT_T)  # (the NaN is the output at the end of that step)
    assert result.signals.t_s.iloc[-1] == pytest.approx(result.t_end_s)
    assert len(result.signals) == round(result.t_end_s / 0.01)
    assert result.t_end_s - 0.04 <= result.run.tracks.t_s.max() <= result.t_end_s  # tracks at 25 Hz
    assert result.run.belts.t_s.max() == pytest.approx(result.t_end_s)


@pytest.mark.parametrize("fault", [1, 2, 5], ids=["error", "fatal", "nan"])
def test_failing_fmu_in_process_stops_the_run_naming_fmu_time_and_status(faulty_fmu: Path, fault: int) -> None:
    sc = load_scenario(PAPER, faulty_overrides(faulty_fmu, fault, "in-process"))
    assert_stopped_at_the_fault(run_scenario(sc), fault)


def _worker_processes() -> list[psutil.Process]:
    return [p for p in psutil.Process().children(recursive=True)
            if "fishfmu.fmu.worker" in " ".join(p.cmdline())]


@pytest.mark.parametrize("fault", [1, 2, 3, 4], ids=["error", "fatal", "hang", "crash"])
def test_failing_hanging_or_crashing_fmu_in_a_worker_leaves_the_orchestrator_running(faulty_fmu: Path,
                                                                                       fault: int) -> None:
    sc = load_scenario(PAPER, faulty_overrides(faulty_fmu, fault, "worker"))
    t0 = time.monotonic()
    result = run_scenario(sc)  # a segmentation fault in the FMU would end this process if it ran here
    assert_stopped_at_the_fault(result, fault)
    if fault == 3:  # the hang is cut at the step timeout (1 s), not waited out
        assert time.monotonic() - t0 < 20.0
    assert _worker_processes() == []  # no worker left behind, killed or not


def test_worker_mode_gives_the_same_signals_as_in_process(faulty_fmu: Path) -> None:
    a = run_scenario(load_scenario(PAPER, faulty_overrides(faulty_fmu, 0, "in-process")))
    b = run_scenario(load_scenario(PAPER, faulty_overrides(faulty_fmu, 0, "worker")))
    assert a.status == b.status == "ok"
    pd.testing.assert_frame_equal(a.signals, b.signals, check_exact=True)
    pd.testing.assert_frame_equal(a.run.tracks, b.run.tracks, check_exact=True)


def _cli(*args: str, cwd: Path, **popen) -> subprocess.Popen:
    env = dict(os.environ, CI="true")
    return subprocess.Popen([sys.executable, "-m", "fishfmu.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd, env=env, **popen)


def write_scenario(path: Path, overrides: dict) -> Path:
    """The paper scenario with ``overrides`` applied, as a file (what a user would write)."""
    import tomllib

    import tomli_w

    from fishfmu.scenario.keys import set_dotted
    data = tomllib.loads(PAPER.read_text())
    for key, value in overrides.items():
        set_dotted(data, key, value)
    path.write_text(tomli_w.dumps(data))
    return path


def test_crashing_fmu_exits_3_and_writes_what_was_recorded(faulty_fmu: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    scenario = write_scenario(tmp_path / "crash.toml", faulty_overrides(faulty_fmu, 4, "worker"))
    proc = _cli("run", str(scenario), "--out", str(out), "--no-report", cwd=tmp_path)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 3, stderr
    assert "Traceback" not in stderr
    assert (f"simulation failed: at t = {FAULT_T:.3f} s: FMU 'drive_c1': its worker process died during doStep "
            "(killed by signal SIGSEGV)") in stderr
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["status"] == "failed" and kpis["t_end_s"] == pytest.approx(FAULT_T) and "SIGSEGV" in kpis["error"]
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "failed" and "SIGSEGV" in info["error"]
    assert pd.read_csv(out / "signals.csv").t_s.max() == pytest.approx(FAULT_T)
    assert read_dataset(out / "run").runs[0].belts.t_s.max() == pytest.approx(FAULT_T)


# ---------------------------------------------------------------- the plant: blow-ups

def test_energy_from_nowhere_is_caught_in_the_next_step_naming_time_and_fish() -> None:
    line = straight_line(("c1", 0.0, 2.0, 0.0))
    plant = Plant(line, [fish("f01", t_s=0.0), fish("f02", x_m=1.4, t_s=0.0)])
    watch = EnergyWatch()
    for _ in range(60):  # both fish land and ride the belt: no alarm
        plant.step({"c1": 0.3})
        watch.check(plant.state, 0.01)
    assert 0.0 <= watch.worst_excess_j < 0.2 * spring_reserve_j(5.0)
    # inject energy: f02 (slot 1) thrown upwards at 5 m/s, well below the 25 m/s blow-up speed
    sd = plant.model.mbs.systemData
    v = sd.GetODE2Coordinates_t()
    v[plant.model.body_ltg[5:10, 2]] = 5.0
    sd.SetODE2Coordinates_t(v)
    plant.step({"c1": 0.3})
    with pytest.raises(SimulationError) as failure:
        watch.check(plant.state, 0.01)
    assert failure.value.time_s == pytest.approx(0.61)
    assert "fish 'f02'" in str(failure.value) and "more energy than the belts supplied" in str(failure.value)


def test_unstable_integration_step_is_stopped_by_the_energy_watch_before_the_speed_limit(monkeypatch) -> None:
    # 5 ms instead of 1.25 ms: contact is unstable; the energy watch must stop the run, with the time
    # and the fish, before the fish reach the 25 m/s blow-up speed
    sc = load_scenario(PAPER, {"fish.count": 1, "run.duration_s": 4.5, "fish.first_drop_s": 3.5,
                               "plant.numerics.step_s": 0.005, "expect": {}})
    result = run_scenario(sc)
    assert result.status == "failed"
    assert "numerical blow-up: the fish gained" in result.error and "fish 'f01'" in result.error
    assert len(result.signals) > 300 and result.signals.t_s.iloc[-1] == pytest.approx(result.t_end_s)
    import plant.sim.health
    monkeypatch.setattr(plant.sim.health, "RESERVE_MIN_J", 1e12)
    late = run_scenario(sc)
    assert "moves at" in late.error and late.t_end_s > result.t_end_s  # the speed check alone: later


# ---------------------------------------------------------------- interrupts

@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)], ids=["SIGTERM", "SIGINT"])
def test_interrupted_run_writes_a_readable_partial_result(tmp_path: Path, signum: int, code: int) -> None:
    out = tmp_path / "out"
    proc = _cli("run", str(PAPER), "--out", str(out), "--no-report", "--set", "fish.count=2",
                "--set", "run.stop_when_clear=false", "--set", "run.duration_s=600", cwd=tmp_path)
    deadline = time.monotonic() + 120
    while not (out / "run_info.json").exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(1.5)  # well into the run
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    assert f"stopped: interrupted by {signal.Signals(signum).name} at t = " in stderr
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["status"] == "partial" and 0.0 < kpis["t_end_s"] < 600.0
    assert kpis["error"].startswith(f"interrupted by {signal.Signals(signum).name} at t = ")
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "partial" and signal.Signals(signum).name in info["error"]
    assert pd.read_csv(out / "signals.csv").t_s.max() == pytest.approx(kpis["t_end_s"])
    assert read_dataset(out / "run").runs[0].belts.t_s.max() == pytest.approx(kpis["t_end_s"])
    assert not [p for p in out.rglob("*") if p.name.endswith(".part") or ".part." in p.name]
    # a partial run is fishfmu's: --overwrite replaces it
    again = _cli("run", str(PAPER), "--out", str(out), "--no-report", "--set", "fish.count=1",
                 "--set", "run.duration_s=0.05", "--set", "expect={}", "--overwrite", cwd=tmp_path)
    assert again.wait(timeout=300) == 0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper_dump", "gap_control", "user_fmu", "reject_doubles"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_energy_watch_stays_far_from_its_reserve_in_the_shipped_scenarios(name: str, seed: int, tmp_path: Path,
                                                                          builtin_fmus) -> None:
    overrides: dict = {"run.seed": seed}
    if name == "user_fmu":
        from fishfmu.fmu.build import build_fmu
        overrides["fmu[1].path"] = str(build_fmu("conveyor_drive", tmp_path, {"rated_power": 370.0,
                                                                             "gear_ratio": 10.0,
                                                                             "ramp_acceleration": 0.5}))
    result = run_scenario(load_scenario(ROOT / "scenarios" / f"{name}.toml", overrides))
    assert result.status == "ok", result.error
    assert result.energy_watch["worst_fraction_of_reserve"] < 0.3, result.energy_watch


def test_a_killed_run_leaves_a_folder_marked_running_that_only_overwrite_replaces(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _cli("run", str(PAPER), "--out", str(out), "--no-report", "--set", "fish.count=1",
                "--set", "run.duration_s=600", "--set", "run.stop_when_clear=false", cwd=tmp_path)
    deadline = time.monotonic() + 120
    while not (out / "run_info.json").exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(0.5)
    proc.kill()  # SIGKILL: no handler runs, nothing is finished
    proc.communicate(timeout=60)
    assert json.loads((out / "run_info.json").read_text())["status"] == "running"
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".fishfmu-manifest")) == ["run_info.json"]  # no result that looks complete
    again = _cli("run", str(PAPER), "--out", str(out), "--no-report", cwd=tmp_path)
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 2 and "holds an earlier run that did not finish (killed?); pass --overwrite" in stderr
