"""A photo-eye with a latency (``latency_s`` on a photo-eye of ``[line]``): the plant reports its blocked signal that
much late, both edges alike, in the signals it serves and in the recorded photoeyes.csv; at 0 nothing changes."""

from __future__ import annotations

import numpy as np
import pytest

from plant.contract.line import KpiSettings, Line
from plant.contract.measured import Dataset, Run, read_dataset, write_dataset
from plant.sim.plant import Plant
from plant.sim.sensors import BeamDelay
from plant.sim.simulate import simulate_plant
from tests.plant_helpers import fish, straight_line

BELT_MPS = 0.5
STEP_S = 0.01


def two_eyes(latency_s: float) -> Line:
    """One belt, two beams at the same place: ``pe`` on time, ``late`` with the latency."""
    line = straight_line(("c1", 0.0, 3.0, 0.0), photoeyes=(("pe", 2.0, 0.015), ("late", 2.0, 0.015)))
    data = line.model_dump()
    data["photoeyes"][1]["latency_s"] = latency_s
    return Line.model_validate(data)


def test_the_delay_holds_each_beam_back_by_its_own_whole_steps():
    # 0.03 s at 10 ms steps is 3 steps; 0.034 rounds to 3, 0.035 (half a step over) to 4; 0 passes through
    delay = BeamDelay([0.0, 0.03, 0.034, 0.035], STEP_S)
    assert delay.steps.tolist() == [0, 3, 3, 4]
    states = [np.array([k in (2, 3, 4, 5)] * 4) for k in range(12)]  # blocked at steps 2-5 (4 steps long)
    out = np.array([delay(s) for s in states])
    assert np.flatnonzero(out[:, 0]).tolist() == [2, 3, 4, 5]
    assert np.flatnonzero(out[:, 1]).tolist() == [5, 6, 7, 8] == np.flatnonzero(out[:, 2]).tolist()
    assert np.flatnonzero(out[:, 3]).tolist() == [6, 7, 8, 9]


@pytest.fixture(scope="module")
def ridden():
    """A 0.6 m fish riding a belt at 0.5 m/s past both beams (5 s simulated)."""
    return simulate_plant(two_eyes(0.03), [fish(x_m=0.6)], {"c1": BELT_MPS}, 5.0)


def test_a_fish_alone_at_a_known_speed_is_reported_late_by_the_latency_with_the_same_blocked_time(ridden):
    """A 0.6 m fish rides a belt at 0.5 m/s past two beams at x = 2 m, one reporting 30 ms late: each of its edges,
    on and off, comes exactly 3 steps later, the blocked time is the same, and between the on edges the fish (by its
    track) moved on by 0.5 m/s x 0.03 s = 15 mm."""
    run = ridden
    pe = run.photoeyes.set_index("sensor_id")
    assert len(pe.loc[["pe"]]) == 1 and len(pe.loc[["late"]]) == 1  # one unbroken passage at each
    on, off = float(pe.loc["pe", "t_on_s"]), float(pe.loc["pe", "t_off_s"])
    late_on, late_off = float(pe.loc["late", "t_on_s"]), float(pe.loc["late", "t_off_s"])
    assert late_on - on == pytest.approx(0.03, abs=1e-9)
    assert late_off - off == pytest.approx(0.03, abs=1e-9)
    # the passage itself: about the fish's length over the belt's speed (its outline at the beam's height)
    assert 0.8 * 0.6 / BELT_MPS < off - on < 1.1 * 0.6 / BELT_MPS
    x = lambda t: float(np.interp(t, run.tracks["t_s"], run.tracks["x_m"]))  # noqa: E731
    assert x(late_on) - x(on) == pytest.approx(BELT_MPS * 0.03, abs=0.002)


def test_the_served_signal_is_the_one_reported_late():
    """Stepping the plant as a co-simulation (what OPC UA and the FMU serve): the late eye's output at each step is
    the on-time eye's of three steps before."""
    plant = Plant(two_eyes(0.03), [fish(x_m=1.2)], comm_step_s=STEP_S)
    pe, late = [], []
    for _ in range(300):
        out = plant.step({"c1": BELT_MPS})
        pe.append(out.photoeyes["pe"])
        late.append(out.photoeyes["late"])
    assert any(pe)  # the fish reached the beam
    assert late[3:] == pe[:-3] and not any(late[:3])


def test_without_latency_a_line_written_out_is_as_before_and_with_it_a_dataset_keeps_it(ridden, tmp_path):
    assert "latency_s" not in two_eyes(0.0).model_dump(mode="json")["photoeyes"][1]
    assert two_eyes(0.0).photoeyes[1].latency_s == 0.0
    kpi = KpiSettings(outfeed_photoeye="pe")
    run = Run("r1", None, "", ridden.fish, ridden.tracks, ridden.photoeyes, ridden.belts)
    write_dataset(Dataset("on_time", "", two_eyes(0.0), kpi, [run]), tmp_path / "on_time")
    assert "latency_s" not in (tmp_path / "on_time" / "dataset.toml").read_text()
    write_dataset(Dataset("late", "", two_eyes(0.03), kpi, [run]), tmp_path / "late")
    back = read_dataset(tmp_path / "late")
    assert [p.latency_s for p in back.line.photoeyes] == [0.0, 0.03]
    assert back.runs[0].photoeyes[["t_on_s", "t_off_s"]].to_numpy() == pytest.approx(
        ridden.photoeyes[["t_on_s", "t_off_s"]].to_numpy())
