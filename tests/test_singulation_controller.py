"""The singulation controller FMU on scripted photo-eye sequences, stepped through fmpy.

Times are checked to one scan: the controller acts at its scans, every scan_time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from tests.fmu_helpers import Slave, run_script, start_slave, start_values

SCAN_S = 0.01


@pytest.fixture(scope="module")
def ctrl_dir(unzipped_fmus: dict[str, Path]) -> Path:
    return unzipped_fmus["singulation_controller"]


@pytest.fixture(scope="module")
def speeds(ctrl_dir: Path) -> dict[int, float]:
    """Nominal belt speeds as the FMU's defaults give them."""
    start = start_values(ctrl_dir)
    return {i: start[f"speed_{i}"] for i in range(1, 9)}


def line_params(n_belts: int = 3, **extra: float | int | bool) -> dict:
    """All belts running from t = 0 and a 10 ms scan, so that the scripts below control the timing."""
    return {"n_belts": n_belts, "startup_delay": 0.0, "scan_time": SCAN_S, **extra}


def measured_speeds(speeds: dict[int, float], n_belts: int) -> dict[str, float]:
    return {f"belt_speed_{i}": speeds[i] for i in range(1, n_belts + 1)}


def first_time(t: np.ndarray, condition: np.ndarray) -> float:
    return float(t[np.argmax(condition)]) if condition.any() else float("inf")


# ---------------------------------------------------------------- start-up

def test_belts_start_downstream_first_one_delay_apart(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    n, delay_s = 4, 1.5
    slave = start_slave(ctrl_dir, {"n_belts": n, "startup_delay": delay_s, "scan_time": SCAN_S})
    at_start = slave.get(*(f"setpoint_{i}" for i in range(1, 9)))
    names = [f"setpoint_{i}" for i in range(1, 9)]
    out = run_script(slave, [], 6.0, 0.01, *names)
    slave.close()
    assert at_start["setpoint_4"] == speeds[4]  # the last belt runs from t = 0
    assert all(at_start[f"setpoint_{i}"] == 0.0 for i in (1, 2, 3))
    for i in range(1, n + 1):
        start_s = first_time(out["t"], out[f"setpoint_{i}"] > 0.0) if i < n else 0.0
        assert start_s == pytest.approx((n - i) * delay_s, abs=SCAN_S + 1e-9), i
        assert out[f"setpoint_{i}"][-1] == speeds[i]
    for i in range(n + 1, 9):  # belts the line does not have stay off
        assert np.all(out[f"setpoint_{i}"] == 0.0)


# ---------------------------------------------------------------- gap control

def gap_script(clear_s: float, head_s: float = 0.2, tail_s: float = 0.6) -> list[tuple[float, dict]]:
    """Eye 1: a fish from head_s to tail_s, then the next fish's head clear_s later."""
    return [(head_s, {"pe_1": True}), (tail_s, {"pe_1": False}), (tail_s + clear_s, {"pe_1": True}),
            (tail_s + clear_s + 0.3, {"pe_1": False})]


def test_short_gap_holds_the_belt_for_hold_time(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    gap_target_m, hold_time_s, hold_factor = 0.3, 0.5, 0.3
    slave = start_slave(ctrl_dir, line_params(mode=1, gap_target=gap_target_m, hold_time=hold_time_s,
                                              hold_factor=hold_factor), inputs=measured_speeds(speeds, 3))
    clear_s = 0.2  # gap = 0.2 s x speed of belt 2, the belt that carries the first fish away
    out = run_script(slave, gap_script(clear_s), 2.0, SCAN_S, "setpoint_1", "setpoint_2", "gap_events",
                     "last_gap_m_1", "holding_1")
    slave.close()
    gap_m = clear_s * speeds[2]
    assert gap_m < gap_target_m
    assert out["last_gap_m_1"][-1] == pytest.approx(gap_m, abs=SCAN_S * speeds[2] + 1e-9)
    held = out["setpoint_1"] < speeds[1]
    assert out["setpoint_1"][held] == pytest.approx(hold_factor * speeds[1], rel=1e-12)
    assert first_time(out["t"], held) == pytest.approx(0.6 + clear_s, abs=SCAN_S + 1e-9)
    assert held.sum() * SCAN_S == pytest.approx(hold_time_s, abs=SCAN_S + 1e-9)
    assert np.all(np.diff(np.flatnonzero(held)) == 1)  # one hold, not several
    assert np.array_equal(out["holding_1"] == 1, held)
    assert out["gap_events"][-1] == 1
    assert np.all(out["setpoint_2"] == speeds[2])  # only the belt before the eye is held


def test_long_gap_does_not_hold(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    slave = start_slave(ctrl_dir, line_params(mode=1, gap_target=0.3), inputs=measured_speeds(speeds, 3))
    clear_s = 0.8
    out = run_script(slave, gap_script(clear_s), 2.5, SCAN_S, "setpoint_1", "gap_events", "last_gap_m_1")
    slave.close()
    assert clear_s * speeds[2] > 0.3
    assert out["last_gap_m_1"][-1] == pytest.approx(clear_s * speeds[2], abs=SCAN_S * speeds[2] + 1e-9)
    assert np.all(out["setpoint_1"] == speeds[1])
    assert out["gap_events"][-1] == 0


@pytest.mark.parametrize("carry_speed_mps, expect_hold", [(1.0, True), (2.0, False)])
def test_gap_is_measured_with_the_speed_of_the_carrying_belt(ctrl_dir: Path, speeds: dict[int, float],
                                                            carry_speed_mps: float, expect_hold: bool) -> None:
    # 0.2 s clear: 0.2 m at 1 m/s (short), 0.4 m at 2 m/s (long); belt 1's own speed must not matter
    inputs = {**measured_speeds(speeds, 3), "belt_speed_2": carry_speed_mps}
    slave = start_slave(ctrl_dir, line_params(mode=1, gap_target=0.3), inputs=inputs)
    out = run_script(slave, gap_script(0.2), 1.5, SCAN_S, "gap_events", "last_gap_m_1")
    slave.close()
    assert out["last_gap_m_1"][-1] == pytest.approx(0.2 * carry_speed_mps, abs=SCAN_S * carry_speed_mps + 1e-9)
    assert out["gap_events"][-1] == (1 if expect_hold else 0)


def test_fixed_mode_measures_gaps_but_ignores_them(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    slave = start_slave(ctrl_dir, line_params(mode=0, gap_target=0.3), inputs=measured_speeds(speeds, 3))
    out = run_script(slave, gap_script(0.1), 1.5, SCAN_S, "setpoint_1", "gap_events", "last_gap_m_1")
    slave.close()
    assert out["last_gap_m_1"][-1] == pytest.approx(0.1 * speeds[2], abs=SCAN_S * speeds[2] + 1e-9)
    assert np.all(out["setpoint_1"] == speeds[1])
    assert out["gap_events"][-1] == 0


def test_first_fish_is_not_a_gap(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    # an empty line in front of the first fish is no short gap, however soon the fish arrives
    slave = start_slave(ctrl_dir, line_params(mode=1), inputs=measured_speeds(speeds, 3))
    out = run_script(slave, [(0.05, {"pe_1": True})], 0.5, SCAN_S, "gap_events", "last_gap_m_1")
    slave.close()
    assert out["gap_events"][-1] == 0 and out["last_gap_m_1"][-1] == -1.0


def test_scan_timing_does_not_depend_on_communication_step(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    results = []
    for dt_s in (0.001, 0.01, 0.05):
        slave = start_slave(ctrl_dir, line_params(mode=1, gap_target=0.3), inputs=measured_speeds(speeds, 3))
        out = run_script(slave, gap_script(0.2, head_s=0.2, tail_s=0.6), 2.0, dt_s, "setpoint_1")
        slave.close()
        stride = round(0.05 / dt_s)
        results.append(out["setpoint_1"][stride - 1::stride])
    assert np.array_equal(results[0], results[1]) and np.array_equal(results[0], results[2])


# ---------------------------------------------------------------- jams

def test_jam_is_raised_after_jam_time_stops_upstream_and_clears(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    jam_s, clear_s = 2.0, 0.5
    slave = start_slave(ctrl_dir, line_params(jam_time=jam_s, jam_clear_time=clear_s, jam_stop=True),
                        inputs=measured_speeds(speeds, 3))
    script = [(1.0, {"pe_2": True}), (4.0, {"pe_2": False})]
    out = run_script(slave, script, 5.5, SCAN_S, "jam", "jam_belt", "setpoint_1", "setpoint_2", "setpoint_3")
    slave.close()
    jam = out["jam"] == 1
    assert first_time(out["t"], jam) == pytest.approx(1.0 + jam_s, abs=SCAN_S + 1e-9)
    assert np.all(out["jam_belt"][jam] == 2) and np.all(out["jam_belt"][~jam] == 0)
    # the jam holds while the eye is blocked and for clear_s after it clears
    assert out["t"][jam][-1] == pytest.approx(4.0 + clear_s, abs=SCAN_S + 1e-9)
    assert np.all(out["setpoint_1"][jam] == 0.0) and np.all(out["setpoint_2"][jam] == 0.0)
    assert np.all(out["setpoint_3"] == speeds[3])  # downstream keeps carrying fish away
    assert out["setpoint_1"][-1] == speeds[1] and out["setpoint_2"][-1] == speeds[2]


def test_jam_without_jam_stop_only_reports(ctrl_dir: Path, speeds: dict[int, float]) -> None:
    slave = start_slave(ctrl_dir, line_params(jam_time=1.0, jam_stop=False), inputs=measured_speeds(speeds, 3))
    out = run_script(slave, [(0.0, {"pe_3": True})], 1.5, SCAN_S, "jam", "jam_belt", "setpoint_1")
    slave.close()
    assert out["jam"][-1] == 1 and out["jam_belt"][-1] == 3
    assert np.all(out["setpoint_1"] == speeds[1])


# ---------------------------------------------------------------- bad values

@pytest.mark.parametrize("name, value, message", [
    ("n_belts", 9, "'n_belts' = 9 is outside its range [1, 8]"),
    ("belt_speed_2", float("nan"), "'belt_speed_2' = nan is not a finite number"),
    ("jam", True, "'jam' cannot be set"),
])
def test_bad_values_are_rejected_with_a_log_message(ctrl_dir: Path, name: str, value: float, message: str) -> None:
    log: list[str] = []
    with pytest.raises(FMICallException):
        start_slave(ctrl_dir, {name: value}, log=log)
    assert any(message in line for line in log), log
