"""The conveyor drive FMU against the drive's equations worked out by hand from its own parameters.

Every parameter value below comes from the modelDescription's start values (the FMU's defaults) or
is set explicitly in the test; nothing is copied from a previous run.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from tests.fmu_helpers import Slave, start_slave, start_values

RPM = 2.0 * math.pi / 60.0


@pytest.fixture(scope="module")
def drive_dir(unzipped_fmus: dict[str, Path]) -> Path:
    return unzipped_fmus["conveyor_drive"]


@pytest.fixture(scope="module")
def p(drive_dir: Path) -> dict[str, float]:
    return start_values(drive_dir)


# ---------------------------------------------------------------- the drive by hand

def rated_torque_nm(p: dict[str, float]) -> float:
    return p["rated_power"] / (p["rated_speed"] * RPM)


def slip_stiffness(p: dict[str, float]) -> float:
    """k_slip: rated torque over rated slip, N.m per rad/s."""
    return rated_torque_nm(p) / ((p["synchronous_speed"] - p["rated_speed"]) * RPM)


def equivalent_inertia(p: dict[str, float]) -> float:
    r, i = p["drum_radius"], p["gear_ratio"]
    return p["motor_inertia"] + (p["drum_inertia"] + p["belt_mass"] * r * r) / (i * i)


def droop_per_newton(p: dict[str, float]) -> float:
    """Steady belt speed lost per N of belt force without slip compensation: (F r / (i eta)) / k * r / i."""
    r, i = p["drum_radius"], p["gear_ratio"]
    return (r / (i * p["gear_efficiency"])) / slip_stiffness(p) * r / i


def steady_speed_mps(p: dict[str, float], setpoint_mps: float, load_n: float, compensation: float = 0.0) -> float:
    """Solve v = v_set - (1 - s) g (F_load + F_c + c_v v) for v (forward motion, above the smoothing speed)."""
    g = (1.0 - compensation) * droop_per_newton(p)
    return (setpoint_mps - g * (load_n + p["running_resistance_coulomb"])) / (1.0 + g * p["running_resistance_viscous"])


def run(slave: Slave, duration_s: float, dt_s: float, *names: str) -> dict[str, np.ndarray]:
    """Step for duration_s and return the outputs after each step (and the time)."""
    rows = []
    for _ in range(round(duration_s / dt_s)):
        slave.step(dt_s)
        rows.append([slave.time_s, *slave.get(*names).values()])
    table = np.array(rows)
    return {"t": table[:, 0], **{name: table[:, k + 1] for k, name in enumerate(names)}}


# ---------------------------------------------------------------- tests

def test_derived_parameters_match_the_motor_data(drive_dir: Path, p: dict[str, float]) -> None:
    slave = start_slave(drive_dir)
    got = slave.get("rated_torque", "slip_stiffness", "equivalent_inertia")
    slave.close()
    assert got["rated_torque"] == pytest.approx(rated_torque_nm(p), rel=1e-12)
    assert got["slip_stiffness"] == pytest.approx(slip_stiffness(p), rel=1e-12)
    assert got["equivalent_inertia"] == pytest.approx(equivalent_inertia(p), rel=1e-12)
    # the defaults describe the drive asked for: ~1.5 m/s near rated motor speed, > 1.6 m/s at 50 Hz
    sync_speed_at_50hz_mps = p["synchronous_speed"] * RPM * p["drum_radius"] / p["gear_ratio"]
    assert sync_speed_at_50hz_mps > 1.6
    assert 1.5 * p["gear_ratio"] / p["drum_radius"] / RPM == pytest.approx(p["rated_speed"], rel=0.05)


def test_drive_starts_at_rest_and_stays_there_without_setpoint(drive_dir: Path) -> None:
    slave = start_slave(drive_dir)
    assert slave.get("belt_speed", "motor_torque", "electrical_power") == {
        "belt_speed": 0.0, "motor_torque": 0.0, "electrical_power": 0.0}
    out = run(slave, 1.0, 0.05, "belt_speed")
    slave.close()
    assert np.all(out["belt_speed"] == 0.0)


def test_drive_starts_at_the_given_initial_speed(drive_dir: Path) -> None:
    slave = start_slave(drive_dir, {"initial_belt_speed": 0.8}, inputs={"speed_setpoint": 0.8})
    assert slave.value("belt_speed") == pytest.approx(0.8, abs=1e-12)
    assert slave.value("ramp_reference") == pytest.approx(0.8, abs=1e-12)
    slave.close()


def test_steady_droop_under_load_matches_hand_calculation(drive_dir: Path, p: dict[str, float]) -> None:
    setpoint_mps, load_n = 1.2, 150.0
    slave = start_slave(drive_dir, {"slip_compensation": 0.0}, inputs={"speed_setpoint": setpoint_mps,
                                                                        "load_force": load_n})
    # ramp 0.6 s at 2 m/s2, then ~100 time constants of 18 ms
    run(slave, 2.5, 0.01, "belt_speed")
    droop_sim = setpoint_mps - slave.value("belt_speed")
    slave.close()
    droop_hand = setpoint_mps - steady_speed_mps(p, setpoint_mps, load_n)
    assert droop_hand > 0.03  # a droop big enough to measure: 190 N of belt force
    assert droop_sim == pytest.approx(droop_hand, rel=0.02)


@pytest.mark.parametrize("compensation", [0.5, 1.0])
def test_slip_compensation_removes_its_fraction_of_the_droop(drive_dir: Path, p: dict[str, float],
                                                             compensation: float) -> None:
    setpoint_mps, load_n = 1.2, 150.0
    slave = start_slave(drive_dir, {"slip_compensation": compensation},
                        inputs={"speed_setpoint": setpoint_mps, "load_force": load_n})
    run(slave, 6.0, 0.05, "belt_speed")  # filter time constant 0.5 s: 12 of them
    droop_sim = setpoint_mps - slave.value("belt_speed")
    slave.close()
    droop_hand = setpoint_mps - steady_speed_mps(p, setpoint_mps, load_n, compensation)
    droop_uncompensated = setpoint_mps - steady_speed_mps(p, setpoint_mps, load_n)
    assert droop_sim == pytest.approx(droop_hand, abs=0.02 * droop_uncompensated)


def test_small_step_is_first_order_with_time_constant_j_over_k(drive_dir: Path, p: dict[str, float]) -> None:
    # no viscous resistance (it would add c_v r^2/(i^2 eta) to k); Coulomb resistance is constant at speed
    ramp_mps2, v0_mps, step_mps = 50.0, 1.0, 0.01
    params = {"ramp_acceleration": ramp_mps2, "running_resistance_viscous": 0.0, "initial_belt_speed": v0_mps}
    slave = start_slave(drive_dir, params, inputs={"speed_setpoint": v0_mps})
    run(slave, 0.5, 0.01, "belt_speed")  # settle the droop of the running resistance
    before = slave.value("belt_speed")
    slave.set(speed_setpoint=v0_mps + step_mps)
    t0 = slave.time_s
    out = run(slave, 0.3, 0.0005, "belt_speed", "motor_torque")
    slave.close()
    tau_s = equivalent_inertia(p) / slip_stiffness(p)
    assert tau_s == pytest.approx(0.0179, rel=0.01)  # the README's hand number
    # step inside the limits: the ramp takes step/a = 0.2 ms, the torque stays below the limit
    assert out["motor_torque"].max() < p["torque_limit_factor"] * rated_torque_nm(p)
    ramp_delay_s = step_mps / ramp_mps2 / 2  # a short ramp delays a first-order response by half its length
    t = out["t"] - t0
    rise = (out["belt_speed"] - before) / step_mps
    assert rise[-1] == pytest.approx(1.0, abs=1e-3)
    t63 = float(np.interp(1.0 - math.exp(-1.0), rise, t))
    assert t63 - ramp_delay_s == pytest.approx(tau_s, rel=0.02)
    for n_tau in (0.5, 2.0, 4.0):
        expected = 1.0 - math.exp(-n_tau)
        assert float(np.interp(n_tau * tau_s + ramp_delay_s, t, rise)) == pytest.approx(expected, abs=0.02 * expected)


def test_belt_never_accelerates_faster_than_the_ramp(drive_dir: Path, p: dict[str, float]) -> None:
    slave = start_slave(drive_dir, inputs={"speed_setpoint": 1.5, "load_force": 50.0})
    dt_s = 0.001
    out = run(slave, 1.2, dt_s, "belt_speed", "ramp_reference")
    slave.close()
    a = p["ramp_acceleration"]
    assert out["ramp_reference"] == pytest.approx(np.minimum(a * out["t"], 1.5), abs=1e-9)
    accel = np.diff(out["belt_speed"]) / dt_s
    assert accel.max() <= a * 1.001  # tolerance 0.1 %: the lag behind the ramp only ever slows the belt
    assert accel.max() >= a * 0.95  # and the limit is what set the pace (not a trivially slow start)


def test_results_do_not_depend_on_communication_step(drive_dir: Path) -> None:
    """Same input schedule at dt = 1, 10, 50 ms: outputs agree at the common 50 ms sample times.

    With the default 1 ms internal step every dt is split into the same RK4 steps: agreement to
    1e-9 m/s (rounding).  With a 4 ms internal step the substeps differ (1, 3.33, 3.85 ms); the
    tolerance is 1e-4 m/s (0.01 % of the 1.4 m/s run).  A first-order method would miss it by far:
    Euler's error after a setpoint change is ~ h / (2 tau) = 10 % of the transient (tau = 18 ms).
    """
    schedule = [(0.0, 1.4, 0.0), (1.0, 1.4, 120.0), (1.5, 0.6, 120.0)]  # (from t, setpoint, load)

    def simulate(dt_s: float, max_step_s: float) -> np.ndarray:
        slave = start_slave(drive_dir, {"max_internal_step": max_step_s})
        speeds = []
        for k in range(round(2.5 / dt_s)):
            t = k * dt_s
            _, setpoint, load = [row for row in schedule if row[0] <= t + 1e-12][-1]
            slave.set(speed_setpoint=setpoint, load_force=load)
            slave.step(dt_s)
            speeds.append(slave.value("belt_speed"))
        slave.close()
        stride = round(0.05 / dt_s)
        return np.array(speeds)[stride - 1::stride]

    for max_step_s, tolerance_mps in ((0.001, 1e-9), (0.004, 1e-4)):
        reference = simulate(0.001, max_step_s)
        for dt_s in (0.01, 0.05):
            assert np.abs(simulate(dt_s, max_step_s) - reference).max() <= tolerance_mps, (dt_s, max_step_s)


def test_torque_limit_caps_motor_torque_under_overload(drive_dir: Path, p: dict[str, float]) -> None:
    slave = start_slave(drive_dir, {"initial_belt_speed": 1.0}, inputs={"speed_setpoint": 1.0})
    run(slave, 0.5, 0.01, "belt_speed")
    overload_n = 1500.0  # needs 16 N.m at the motor, the limit is ~10 N.m
    slave.set(load_force=overload_n)
    out = run(slave, 0.06, 0.001, "belt_speed", "motor_torque")
    slave.close()
    t_max = p["torque_limit_factor"] * rated_torque_nm(p)
    # the slip grows as the belt slows; beyond T_max / k the torque stays at the limit
    assert out["motor_torque"][:5].max() < t_max
    assert out["motor_torque"][25:] == pytest.approx(t_max, rel=1e-12)
    r, i, eta = p["drum_radius"], p["gear_ratio"], p["gear_efficiency"]
    load_torque = (overload_n + p["running_resistance_coulomb"] + p["running_resistance_viscous"] * out["belt_speed"])
    load_torque = load_torque * r / (i * eta)
    decel_hand = (t_max - load_torque[30:55]) / equivalent_inertia(p) * r / i
    decel_sim = np.gradient(out["belt_speed"], 0.001)[30:55]
    assert np.all(out["belt_speed"] > 0.0)  # still moving forward: the motor drives, divide by eta
    assert decel_sim == pytest.approx(decel_hand, rel=0.02)


def test_electrical_power_is_mechanical_power_over_efficiency(drive_dir: Path, p: dict[str, float]) -> None:
    slave = start_slave(drive_dir, {"initial_belt_speed": 1.5, "ramp_acceleration": 50.0},
                        inputs={"speed_setpoint": 1.5, "load_force": 200.0})
    run(slave, 0.5, 0.01, "belt_speed")
    motoring = slave.get("motor_torque", "motor_speed", "electrical_power")
    slave.set(speed_setpoint=0.5, load_force=0.0)  # braking: the belt's energy flows back
    slave.step(0.005)
    braking = slave.get("motor_torque", "motor_speed", "electrical_power")
    slave.close()
    eta_m = p["motor_efficiency"]
    p_mech = motoring["motor_torque"] * motoring["motor_speed"] * RPM
    assert p_mech > 0.0
    assert motoring["electrical_power"] == pytest.approx(p_mech / eta_m, rel=1e-12)
    p_mech = braking["motor_torque"] * braking["motor_speed"] * RPM
    assert p_mech < 0.0
    assert braking["electrical_power"] == pytest.approx(p_mech * eta_m, rel=1e-12)


@pytest.mark.parametrize("name, value, message", [
    ("speed_setpoint", float("nan"), "'speed_setpoint' = nan is not a finite number"),
    ("speed_setpoint", 5.0, "'speed_setpoint' = 5 is outside its range [-2, 2]"),
    ("load_force", float("inf"), "'load_force' = inf is not a finite number"),
    ("gear_ratio", 7.0, "'gear_ratio' cannot be set in state 'step mode'"),
    ("belt_speed", 1.0, "'belt_speed' cannot be set"),
])
def test_bad_values_are_rejected_with_a_log_message(drive_dir: Path, name: str, value: float, message: str) -> None:
    slave = start_slave(drive_dir)
    with pytest.raises(FMICallException):
        slave.set(**{name: value})
    slave.close()
    assert any(message in line for line in slave.log), slave.log


@pytest.mark.parametrize("params, message", [
    ({"rated_speed": 1500.0}, "rated_speed = 1500 rpm must be below synchronous_speed = 1500 rpm"),
    ({"max_internal_step": 0.05}, "max_internal_step = 0.05 s is too large"),
])
def test_inconsistent_parameters_fail_initialization(drive_dir: Path, params: dict, message: str) -> None:
    log: list[str] = []
    with pytest.raises(FMICallException) as failure:
        start_slave(drive_dir, params, log=log)
    assert failure.value.function == "fmi2ExitInitializationMode"
    assert any(message in line for line in log), log


def test_belt_slip_lowers_the_belt_speed_in_proportion_to_the_load(drive_dir: Path) -> None:
    """The drive_droop extension: belt speed = drum surface speed - belt_slip * load_force."""
    slip, force = 2e-4, 150.0  # (m/s)/N, N
    speeds = []
    for belt_slip in (0.0, slip):
        slave = start_slave(drive_dir, {"ramp_acceleration": 50.0, "belt_slip": belt_slip},
                            inputs={"speed_setpoint": 1.0, "load_force": force})
        speeds.append(run(slave, 2.0, 0.01, "belt_speed")["belt_speed"][-1])
        slave.close()
    assert speeds[1] == pytest.approx(speeds[0] - slip * force, abs=1e-9)
