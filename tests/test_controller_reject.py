"""The singulation controller's reject function on scripted camera results, stepped through fmpy.

A camera result is what the plant's vision sensor gives a scenario to wire to the cam_* inputs; the
controller opens a reject window for the leading fish of a new result that calls for it, in the
travel of belt reject_belt (see the header of fishfmu/fmu/sources/singulation_controller/model.c).

The line of every test: belt 2 carries the fish from the camera to the device at 0.5 m/s, the device
acts at reject_x = 6.5 m, camera_latency 0.04 s, actuator_time 0.2 s, reject_margin 0.05 m.  A double
result at t with its leading fish's front at lead_x and length L: the front is at lead_x + 0.5 x 0.04 at
t, so the device is commanded when the front is margin + 0.5 x 0.2 = 0.15 m short of 6.5 m and released
when the back is 0.05 m past it:

    t_open  = t + (6.5 - 0.15 - (lead_x + 0.02)) / 0.5,
    t_close = t + (6.5 + 0.05 - (lead_x + 0.02 - L)) / 0.5.

Times are checked to one scan: the controller reads a result at the first scan after it was set and
acts at its scans, every scan_time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from tests.fmu_helpers import Slave, run_script, start_slave

SCAN_S = 0.01
V_MPS = 0.5  # belt 2, the one that carries the fish to the device
REJECT_X_M, LATENCY_S, ACTUATOR_S, MARGIN_M = 6.5, 0.04, 0.2, 0.05
SPEEDS = {"belt_speed_1": 0.3, "belt_speed_2": V_MPS, "belt_speed_3": 0.85}  # only belt 2's may count


@pytest.fixture(scope="module")
def ctrl_dir(unzipped_fmus: dict[str, Path]) -> Path:
    return unzipped_fmus["singulation_controller"]


def reject_params(reject_mode: int, **extra: float | int | bool) -> dict:
    return {"n_belts": 3, "startup_delay": 0.0, "scan_time": SCAN_S, "reject_mode": reject_mode,
            "reject_x": REJECT_X_M, "reject_belt": 2, "camera_latency": LATENCY_S, "actuator_time": ACTUATOR_S,
            "reject_margin": MARGIN_M, **extra}


def result(number: int, lead_x_m: float, length_m: float = 0.6, double: bool = True, heading: int = 1) -> dict:
    """Camera result number ``number`` (the cam_results counter) about its leading fish."""
    return {"cam_results": number, "cam_double": double, "cam_lead_x": lead_x_m, "cam_lead_length": length_m,
            "cam_lead_heading": heading}


def window_s(t_s: float, lead_x_m: float, length_m: float = 0.6) -> tuple[float, float]:
    """(t_open, t_close) by hand for a result at t_s, the belt at V_MPS throughout (module docstring)."""
    front_m = lead_x_m + V_MPS * LATENCY_S
    return (t_s + (REJECT_X_M - MARGIN_M - V_MPS * ACTUATOR_S - front_m) / V_MPS,
            t_s + (REJECT_X_M + MARGIN_M - (front_m - length_m)) / V_MPS)


def runs(flag: np.ndarray) -> int:
    """Number of separate stretches where ``flag`` is true."""
    return int(np.count_nonzero(np.diff(np.concatenate([[0], flag.astype(int)])) == 1))


def assert_windows(t: np.ndarray, reject: np.ndarray, windows: list[tuple[float, float]]) -> None:
    """reject is true inside the hand-computed windows and false outside, one scan of slack at each end."""
    on = reject == 1
    assert runs(on) == len(windows), (windows, t[on])
    inside = np.zeros_like(on)
    near_edge = np.zeros_like(on)
    for open_s, close_s in windows:
        inside |= (t >= open_s) & (t <= close_s)
        near_edge |= (np.abs(t - open_s) <= SCAN_S + 1e-9) | (np.abs(t - close_s) <= SCAN_S + 1e-9)
    assert np.array_equal(on[~near_edge], inside[~near_edge]), (windows, t[on][[0, -1]] if on.any() else None)
    for open_s, close_s in windows:  # and the edges themselves are within one scan
        stretch = t[on & (t >= open_s - SCAN_S - 1e-9) & (t <= close_s + SCAN_S + 1e-9)]
        assert stretch[0] == pytest.approx(open_s, abs=SCAN_S + 1e-9)
        assert stretch[-1] == pytest.approx(close_s, abs=SCAN_S + 1e-9)


# ---------------------------------------------------------------- doubles and tail-first fish

def test_double_is_rejected_from_actuator_time_before_its_front_until_its_back_has_passed(ctrl_dir: Path) -> None:
    slave = start_slave(ctrl_dir, reject_params(1), inputs=SPEEDS)
    out = run_script(slave, [(1.0, result(1, lead_x_m=6.0, length_m=0.6))], 4.0, SCAN_S, "reject", "reject_events")
    slave.close()
    # front at 6.0 + 0.5 x 0.04 = 6.02 m at t = 1.0; 0.33 m to go to 6.5 - 0.05 - 0.5 x 0.2 = 6.35 m -> 0.66 s;
    # the back (5.42 m) passes 6.55 m after 1.13 m -> 2.26 s
    assert window_s(1.0, 6.0) == pytest.approx((1.66, 3.26))
    assert_windows(out["t"], out["reject"], [(1.66, 3.26)])
    assert np.count_nonzero(out["reject"]) * SCAN_S == pytest.approx((0.6 + 2 * 0.05 + 0.5 * 0.2) / V_MPS,
                                                                     abs=SCAN_S + 1e-9)  # 1.6 s
    assert np.all(out["reject_events"][out["t"] < 1.0] == 0) and out["reject_events"][-1] == 1


def test_a_device_length_holds_the_window_until_the_back_has_passed_its_far_end(ctrl_dir: Path) -> None:
    slave = start_slave(ctrl_dir, reject_params(1, reject_length=0.4), inputs=SPEEDS)
    out = run_script(slave, [(1.0, result(1, lead_x_m=6.0, length_m=0.6))], 5.0, SCAN_S, "reject")
    slave.close()
    # opens as without it (1.66 s); closes when the back passes 6.5 + 0.4 + 0.05 m: 0.4 m at 0.5 m/s later
    assert_windows(out["t"], out["reject"], [(1.66, 3.26 + 0.4 / V_MPS)])


@pytest.mark.parametrize("reject_mode, rejected", [(1, False), (2, True)])
def test_tail_first_fish_is_rejected_in_mode_2_only(ctrl_dir: Path, reject_mode: int, rejected: bool) -> None:
    script = [(1.0, result(1, lead_x_m=6.0, double=False, heading=-1)),
              (4.0, result(2, lead_x_m=6.0, double=False, heading=1))]  # a single head-first fish: never
    slave = start_slave(ctrl_dir, reject_params(reject_mode), inputs=SPEEDS)
    out = run_script(slave, script, 7.0, SCAN_S, "reject", "reject_events")
    slave.close()
    assert_windows(out["t"], out["reject"], [window_s(1.0, 6.0)] if rejected else [])
    assert out["reject_events"][-1] == (1 if rejected else 0)


def test_a_repeated_result_schedules_nothing_new(ctrl_dir: Path) -> None:
    script = [(1.0, result(1, lead_x_m=6.0)),
              (3.5, result(1, lead_x_m=6.2)),  # other values, the same result number: not a new result
              (4.0, result(2, lead_x_m=6.0))]
    slave = start_slave(ctrl_dir, reject_params(1), inputs=SPEEDS)
    out = run_script(slave, script, 7.0, SCAN_S, "reject", "reject_events")
    slave.close()
    # the double stays on the inputs for 3 s (300 scans) but opens one window; result 2 opens the next
    assert_windows(out["t"], out["reject"], [(1.66, 3.26), (4.66, 6.26)])
    assert out["reject_events"][out["t"] < 4.0][-1] == 1 and out["reject_events"][-1] == 2


def test_a_result_present_at_the_start_is_not_new(ctrl_dir: Path) -> None:
    slave = start_slave(ctrl_dir, reject_params(1), inputs={**SPEEDS, **result(5, lead_x_m=6.0)})
    out = run_script(slave, [], 4.0, SCAN_S, "reject", "reject_events")
    slave.close()
    assert not out["reject"].any() and out["reject_events"][-1] == 0


def test_overlapping_windows_merge_into_one(ctrl_dir: Path) -> None:
    # a second double 0.5 s later, its leading fish's front at 5.9 m: its window (2.36 s .. 3.96 s) starts
    # inside the first one (1.66 s .. 3.26 s), so the device stays open from 1.66 s to 3.96 s
    first, second = window_s(1.0, 6.0), window_s(1.5, 5.9)
    assert second == pytest.approx((2.36, 3.96)) and first[0] < second[0] <= first[1]
    slave = start_slave(ctrl_dir, reject_params(1), inputs=SPEEDS)
    out = run_script(slave, [(1.0, result(1, 6.0)), (1.5, result(2, 5.9))], 5.0, SCAN_S, "reject", "reject_events")
    slave.close()
    assert_windows(out["t"], out["reject"], [(first[0], second[1])])
    assert out["reject_events"][-1] == 1


def test_mode_0_never_rejects_and_changes_nothing_else(ctrl_dir: Path) -> None:
    camera = [(0.5 + 0.1 * k, result(k + 1, lead_x_m=5.5 + 0.05 * k, double=k % 2 == 0, heading=-1))
              for k in range(30)]
    eyes = [(0.2, {"pe_1": True}), (0.6, {"pe_1": False}), (0.7, {"pe_1": True}), (1.0, {"pe_1": False}),
            (1.5, {"pe_2": True})]
    names = ("setpoint_1", "setpoint_2", "setpoint_3", "holding_1", "gap_events", "jam", "last_gap_m_1")
    outs = []
    for script in (eyes, eyes + camera):
        slave = start_slave(ctrl_dir, reject_params(0, mode=1, jam_time=1.0), inputs=SPEEDS)
        outs.append(run_script(slave, script, 6.0, SCAN_S, *names, "reject", "reject_events"))
        slave.close()
    without, with_camera = outs
    assert not with_camera["reject"].any() and with_camera["reject_events"][-1] == 0
    assert with_camera["gap_events"][-1] == 1 and with_camera["jam"].any()  # the rest of the logic did act
    for name in names:  # the same, bit for bit, whatever the camera says
        assert np.array_equal(with_camera[name], without[name]), name


# ---------------------------------------------------------------- travel, not time

def test_a_speed_change_after_the_result_moves_the_window_with_the_fish(ctrl_dir: Path) -> None:
    # Result at 1.0 s, read at the scan of 1.01 s with belt 2 at 0.5 m/s: the window opens 0.33 m and closes
    # 1.13 m of travel after that scan.  Belt 2 slows to 0.25 m/s at 1.2 s: 0.19 s x 0.5 = 0.095 m by 1.2 s,
    # then 0.235 m / 0.25 m/s = 0.94 s -> opens at 2.14 s; 1.035 m / 0.25 m/s = 4.14 s -> closes at 5.34 s.
    # (A window kept in time would open at 1.67 s and close at 3.27 s; the ideal from 1.0 s, 2.12 s, is two
    # scans earlier because the scan of reading, 0.005 m at 0.5 m/s, takes two scans to travel at 0.25 m/s.)
    read_s = 1.0 + SCAN_S
    open_s = 1.2 + (0.33 - (1.2 - read_s) * V_MPS) / 0.25
    close_s = 1.2 + (1.13 - (1.2 - read_s) * V_MPS) / 0.25
    assert (open_s, close_s) == pytest.approx((2.14, 5.34))
    slave = start_slave(ctrl_dir, reject_params(1), inputs=SPEEDS)
    out = run_script(slave, [(1.0, result(1, 6.0)), (1.2, {"belt_speed_2": 0.25, "belt_speed_3": 2.0})], 6.5, SCAN_S,
                     "reject", "reject_events")
    slave.close()
    assert_windows(out["t"], out["reject"], [(open_s, close_s)])
    assert out["reject_events"][-1] == 1


def test_reject_belt_chooses_the_speed_that_counts(ctrl_dir: Path) -> None:
    # belt 3 at 0.85 m/s carries the fish instead: front at 6.0 + 0.85 x 0.04 = 6.034 m; opens when it is
    # 0.05 + 0.85 x 0.2 = 0.22 m short of 6.5 m, closes when the back (5.434 m) is 0.05 m past it
    open_s = 1.0 + SCAN_S + (6.5 - 0.22 - 6.034) / 0.85
    close_s = 1.0 + SCAN_S + (6.55 - 5.434) / 0.85
    slave = start_slave(ctrl_dir, reject_params(1, reject_belt=3), inputs=SPEEDS)
    out = run_script(slave, [(1.0, result(1, 6.0))], 3.0, SCAN_S, "reject")
    slave.close()
    assert_windows(out["t"], out["reject"], [(open_s, close_s)])


# ---------------------------------------------------------------- limits and bad values

def test_a_full_window_list_merges_into_the_last_window_and_says_so(ctrl_dir: Path) -> None:
    # 33 doubles one scan apart, 1 m apart along the line and 90 m before the device: none overlaps and none
    # closes during the run, so the 33rd finds 32 windows pending
    slave = start_slave(ctrl_dir, reject_params(1, reject_x=100.0), inputs=SPEEDS)
    script = [(1.0 + k * SCAN_S, result(k + 1, lead_x_m=10.0 - k, length_m=0.2)) for k in range(33)]
    out = run_script(slave, script, 1.5, SCAN_S, "reject", "reject_events")
    slave.close()
    assert out["reject_events"][-1] == 32 and not out["reject"].any()
    assert sum("32 windows are pending" in line for line in slave.log) == 1, slave.log


@pytest.mark.parametrize("name, value, message", [
    ("reject_mode", 3, "'reject_mode' = 3 is outside its range [0, 2]"),
    ("reject_belt", 9, "'reject_belt' = 9 is outside its range [1, 8]"),
    ("cam_lead_heading", -2, "'cam_lead_heading' = -2 is outside its range [-1, 1]"),
    ("reject", True, "'reject' cannot be set"),
])
def test_bad_reject_values_are_rejected_with_a_log_message(ctrl_dir: Path, name: str, value: float,
                                                           message: str) -> None:
    log: list[str] = []
    with pytest.raises(FMICallException):
        start_slave(ctrl_dir, {name: value}, log=log)
    assert any(message in line for line in log), log
