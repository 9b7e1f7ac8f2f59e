"""The co-simulation master and the run command, on a shortened paper scenario (5 fish)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from plant.contract.kpis import compute_kpis
from plant.contract.measured import read_dataset

from fishfmu.output.run_folder import prepare_out_dir, write_outputs
from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
SHORT = {"fish.count": 5, "run.duration_s": 25.0, "fish.first_drop_s": 3.5}


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    sc = load_scenario(PAPER, SHORT)
    result = run_scenario(sc, PAPER)
    out = prepare_out_dir(tmp_path_factory.mktemp("run") / "out", overwrite=False)
    write_outputs(result, out)
    return result, out


def test_short_paper_run_passes_every_fish_and_writes_all_outputs(short_run):
    result, out = short_run
    assert result.status == "ok"
    assert result.kpis["fish_in"] == 5 and result.kpis["lost"] == 0
    for name in ("scenario.resolved.toml", "kpis.json", "signals.csv", "report.html", "run_info.json",
                 "belts.png", "fish_x.png", "outfeed_gaps.png", "run/dataset.toml"):
        assert (out / name).exists(), name
    # the run in the measured-data format reads back and gives the same KPIs
    ds = read_dataset(out / "run")
    again = compute_kpis(ds.runs[0], ds.line, ds.kpi)
    saved = json.loads((out / "kpis.json").read_text())
    for k in ("singulated", "throughput_time_s", "fish_in", "lost"):
        assert again[k] == pytest.approx(saved[k])
    assert json.loads((out / "run_info.json").read_text())["status"] == "ok"


def test_gauss_seidel_plant_runs_at_the_speed_its_drive_just_computed(short_run):
    s = short_run[0].signals
    for c in ("c1", "c2", "c3", "c4"):
        assert np.array_equal(s[f"plant.{c}.speed"].to_numpy(), s[f"drive_{c}.belt_speed"].to_numpy())
        assert np.array_equal(s[f"drive_{c}.speed_setpoint"].to_numpy(), s[f"controller.setpoint_{c[1]}"].to_numpy())


def test_controller_starts_the_line_downstream_first_and_drives_follow_their_ramp(short_run):
    s = short_run[0].signals
    delay = 1.0  # startup_delay in paper_dump.toml; belt i starts at (4 - i) * delay
    for i, speed in ((1, 0.25), (2, 0.50), (3, 0.80), (4, 1.25)):
        sp = s[f"controller.setpoint_{i}"]
        t_on = float(s.t_s[sp > 0].iloc[0])
        assert t_on == pytest.approx((4 - i) * delay, abs=0.015)
        assert float(sp.iloc[-1]) == pytest.approx(speed)
    # ramp limit of the drive (2 m/s^2 by default): belt 4 needs 1.25 / 2 = 0.625 s to get near speed
    v4 = s["drive_c4.belt_speed"]
    assert float(v4[s.t_s <= 0.3].max()) <= 2.0 * 0.3 + 0.01
    assert float(v4[(s.t_s > 1.0) & (s.t_s < 2.0)].mean()) == pytest.approx(1.25, rel=0.03)


def test_belt_log_uses_the_controller_setpoint_and_the_belt_speed(short_run):
    result, _ = short_run
    belts = result.run.belts
    sig = result.signals.set_index("t_s")
    b2 = belts[belts.conveyor_id == "c2"].set_index("t_s")
    common = b2.index.intersection(sig.index)
    assert len(common) > 100
    assert np.allclose(b2.loc[common, "setpoint_mps"], sig.loc[common, "controller.setpoint_2"])
    assert np.allclose(b2.loc[common, "speed_mps"], sig.loc[common, "plant.c2.speed"])


def test_event_overrides_a_setpoint_and_reset_restores_it():
    events = [{"t_s": 6.0, "target": "drive_c2.speed_setpoint", "action": "override", "value": 0.0},
              {"t_s": 8.0, "target": "drive_c2.speed_setpoint", "action": "reset"}]
    sc = load_scenario(PAPER, {**SHORT, "fish.count": 1, "run.duration_s": 10.0, "run.stop_when_clear": False,
                               "event": events})
    s = run_scenario(sc).signals
    v = s.set_index("t_s")["plant.c2.speed"]
    # ramp 2 m/s^2: 0.5 m/s -> 0 in 0.25 s; back up in 0.25 s after the reset
    assert v.loc[5.9] == pytest.approx(0.5, abs=0.02)
    assert abs(v.loc[6.4]) < 0.01 and abs(v.loc[7.9]) < 0.01
    assert v.loc[8.5] == pytest.approx(0.5, abs=0.02)
    assert s.set_index("t_s").loc[7.0, "drive_c2.speed_setpoint"] == 0.0
    assert s.set_index("t_s").loc[7.0, "controller.setpoint_2"] == pytest.approx(0.5)


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, CI="true")
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=600)


def test_failed_expect_bound_exits_1_and_is_a_junit_failure(tmp_path: Path):
    text = PAPER.read_text()
    text = text[:text.index("\n[expect]")] + "\n[expect]\nfish_in = { min = 6 }\nlost = { max = 0 }\n"
    scen = tmp_path / "short.toml"
    scen.write_text(text)
    proc = _cli("run", str(scen), "--out", str(tmp_path / "out"), "--junit", str(tmp_path / "junit.xml"),
                "--no-report", "--set", "fish.count=5", "--set", "run.duration_s=25", cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    assert "fish_in = 5 is below the minimum 6 by 1" in proc.stdout
    suite = ET.parse(tmp_path / "junit.xml").getroot()
    assert suite.get("tests") == "2" and suite.get("failures") == "1"
    cases = {c.get("name"): c for c in suite.iter("testcase")}
    assert cases["expect.fish_in"].find("failure") is not None
    assert cases["expect.lost"].find("failure") is None


def test_bad_scenario_exits_2_with_one_clear_line(tmp_path: Path):
    scen = tmp_path / "bad.toml"
    scen.write_text(PAPER.read_text().replace("count = 18", "cuont = 18"))
    proc = _cli("run", str(scen), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert proc.returncode == 2
    assert "fish.cuont" in proc.stderr and "did you mean 'count'" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()


def test_fmu_error_exits_3_names_fmu_time_and_status_and_keeps_results(tmp_path: Path):
    # the drive declares speed_setpoint in [-2, 2] m/s and rejects 5 m/s with fmi2Error
    scen = tmp_path / "fault.toml"
    scen.write_text(PAPER.read_text().replace("[kpi]", "[[event]]\nt_s = 4.0\ntarget = \"drive_c1.speed_setpoint\"\n"
                                              "action = \"override\"\nvalue = 5.0\n\n[kpi]"))
    out = tmp_path / "out"
    proc = _cli("run", str(scen), "--out", str(out), "--no-report", "--set", "fish.count=3", cwd=tmp_path)
    assert proc.returncode == 3, proc.stderr
    assert "FMU 'drive_c1'" in proc.stderr and "at t = 4.0" in proc.stderr and "error" in proc.stderr
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "failed" and "drive_c1" in info["error"]
    signals = pd.read_csv(out / "signals.csv")
    assert signals.t_s.max() == pytest.approx(4.0, abs=0.011)  # everything up to the failure is kept


def test_existing_output_folder_is_not_overwritten_without_asking(tmp_path: Path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    proc = _cli("run", str(PAPER), "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 2 and "notes.txt" in proc.stderr and "not written by fishfmu" in proc.stderr
    assert (out / "notes.txt").read_text() == "keep me"


def test_gap_control_scenario_holds_belts_when_a_gap_is_short():
    sc = load_scenario(ROOT / "scenarios" / "gap_control.toml", SHORT)
    result = run_scenario(sc)
    assert result.status == "ok"  # (the [expect] bounds are for the full batch of 18)
    s = result.signals
    nominal = {1: 0.25, 2: 0.50, 3: 0.80}
    started = s.t_s > 3.5
    held = {i: int(((s[f"controller.setpoint_{i}"] < 0.5 * v) & started).sum()) for i, v in nominal.items()}
    assert sum(held.values()) > 0  # hold_factor = 0: a held belt is stopped for hold_time


def test_user_fmu_scenario_runs_a_drive_given_by_path(tmp_path: Path):
    from fishfmu.fmu.build import build_fmu
    fmu = build_fmu("conveyor_drive", tmp_path, {"rated_power": 370.0, "gear_ratio": 10.0, "ramp_acceleration": 0.5})
    sc = load_scenario(ROOT / "scenarios" / "user_fmu.toml", {**SHORT, "fmu[1].path": str(fmu)})
    result = run_scenario(sc)
    assert result.status == "ok"  # (the [expect] bounds are for the full batch of 18)
    v1 = result.signals.set_index("t_s")["plant.c1.speed"]
    # the ramp baked into this FMU is 0.5 m/s^2: c1 starts at 3 s and needs 0.5 s to reach 0.25 m/s
    assert v1.loc[3.2] == pytest.approx(0.5 * 0.2, abs=0.02)
    assert v1.loc[4.0] == pytest.approx(0.25, abs=0.02)


def test_fmu_with_a_step_multiple_steps_less_often_and_holds_its_outputs():
    sc = load_scenario(PAPER, {**SHORT, "fish.count": 1, "run.duration_s": 2.5, "run.stop_when_clear": False,
                               "fmu[0].step_multiple": 10})
    s = run_scenario(sc).signals
    sp3 = s["controller.setpoint_3"].to_numpy()
    # the controller steps every 0.1 s, at t = 0, 0.1, ...: its outputs change only in the base steps
    # that start a block (recorded at their end, 0.01 s later) and are held through the block
    changes = s.t_s.to_numpy()[1:][np.diff(sp3) != 0]
    assert len(changes) >= 1
    assert np.allclose(np.round((changes - 0.01) / 0.1) * 0.1, changes - 0.01, atol=1e-9)
    # belt 3 starts at 1.0 s: that scan runs in the controller's step from 0.9 to 1.0 s, whose
    # end-of-step outputs (Gauss-Seidel) are used for that block, as a one-step FMU's are for its step
    assert changes[0] == pytest.approx(0.91, abs=1e-9)
