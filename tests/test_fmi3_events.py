"""FMI 3.0 co-simulation FMUs in event mode (issue 44): the master honours early return, enters event mode at the
FMU's event times and updates its discrete states before it steps on.  The FMUs are a stair (time events) and a
bouncing ball (state events) written for these tests in C (tests/fmi3_event_fmus: the Modelica Reference FMUs are not
on a package registry) and built with fishfmu's FMU build machinery; their event times are checked against the
analytic ones."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from fishfmu.cosim.runner import run_scenario
from fishfmu.fmu.archive import open_fmu
from fishfmu.fmu.compile import missing_build_tools
from fishfmu.fmu.instance import InProcessFmu
from fishfmu.scenario.schema import load_scenario
from tests.fmi3_event_fmus import build

pytestmark = pytest.mark.skipif(bool(missing_build_tools()), reason="no C compiler or make to build the test FMUs")
ROOT = Path(__file__).parents[1]
DT_S = 0.1
G, E, H0, V_MIN = 9.81, 0.7, 1.0, 0.1  # the ball's defaults (events.c)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("fmi3_events")
    return {f"{m}{'' if e else 'NoEventMode'}": build(m, out, e) for m in ("Stair", "BouncingBall", "Task")
            for e in (True, False)}


def stepped(fmu: Path, parameters: dict, outputs: list[str], n: int) -> tuple[InProcessFmu, list[dict]]:
    with open_fmu(fmu) as opened:
        inst = InProcessFmu("uut", opened, parameters)
        try:
            rows = []
            for k in range(n):
                inst.do_step(k * DT_S, DT_S)
                rows.append(inst.get(outputs))
        finally:
            inst.terminate()
    return inst, rows


def bounce_times_s(until_s: float) -> list[float]:
    """The ball's bounces worked out by hand: the first after sqrt(2 h0 / g), then flights of 2 v / g, v -> e v."""
    t, v = math.sqrt(2 * H0 / G), math.sqrt(2 * G * H0)
    out = []
    while t <= until_s:
        out.append(t)
        v *= E
        if v < V_MIN:
            break
        t += 2 * v / G
    return out


def test_the_stairs_time_events_are_handled_at_their_times_inside_the_step(fmus):
    period = 0.37  # not a multiple of the 0.1 s step: every event falls inside one
    inst, rows = stepped(fmus["Stair"], {"period": period}, ["counter"], 30)
    assert inst.event_mode
    expected = [k * period for k in range(1, int(3.0 / period) + 1)]
    assert len(inst.event_times_s) == len(expected) == 8
    assert list(inst.event_times_s) == pytest.approx(expected, abs=1e-12)
    ends = DT_S * np.arange(1, 31)
    assert [r["counter"] for r in rows] == list(np.floor(ends / period + 1e-9).astype(int))


def test_the_balls_state_events_are_at_the_analytic_bounce_times(fmus):
    inst, rows = stepped(fmus["BouncingBall"], {}, ["h", "v"], 40)
    expected = bounce_times_s(4.0)
    assert len(expected) >= 6 and len(inst.event_times_s) == len(expected)
    assert list(inst.event_times_s) == pytest.approx(expected, abs=1e-12)
    # every step end on the parabola of its flight: after bounce k the ball leaves the floor at e^k v1
    t1, v1 = expected[0], math.sqrt(2 * G * H0)
    for k, row in enumerate(rows):
        t = (k + 1) * DT_S
        before = [tb for tb in expected if tb <= t]
        if len(before) == len(expected):  # the last bounce left it slower than v_min: it rests on the floor
            h, v = 0.0, 0.0
        elif not before:
            h, v = H0 - G * t * t / 2, -G * t
        else:
            s, v0 = t - before[-1], v1 * E ** len(before)
            h, v = v0 * s - G * s * s / 2, v0 - G * s
        assert (row["h"], row["v"]) == pytest.approx((h, v), abs=1e-9), t
    assert t1 == pytest.approx(0.4515236409857309)


def test_a_ball_whose_bounces_pile_up_is_stopped_with_a_message(fmus):
    """v_min = 0: the flights shrink by e each bounce until they no longer move the clock (Zeno); the master stops at
    MAX_EVENTS_PER_STEP events in one step instead of looping for ever."""
    from plant.errors import SimulationError
    t_rest = math.sqrt(2 * H0 / G) * (1 + 2 * E / (1 - E))  # where the bounce times converge: 2.559 s
    with pytest.raises(SimulationError, match=r"FMU 'uut': more than 10000 events in one step from t = 2\.5"):
        stepped(fmus["BouncingBall"], {"v_min": 0.0}, ["h"], 40)
    assert 2.5 < t_rest < 2.6


def test_an_fmu_without_event_mode_is_stepped_over_its_events_as_before(fmus):
    with_events, ev_rows = stepped(fmus["BouncingBall"], {}, ["h", "v"], 30)
    without, rows = stepped(fmus["BouncingBallNoEventMode"], {}, ["h", "v"], 30)
    assert not without.event_mode and list(without.event_times_s) == []  # one doStep per step: the FMU's own events
    values = np.array([[r["h"], r["v"]] for r in rows])
    assert values == pytest.approx(np.array([[r["h"], r["v"]] for r in ev_rows]), abs=1e-12)  # the same model: only who handles the event differs
    stair, counts = stepped(fmus["StairNoEventMode"], {"period": 0.37}, ["counter"], 30)
    assert not stair.event_mode and counts[-1]["counter"] == 8


def test_a_periodic_input_clock_ticks_at_its_interval_inside_the_steps(fmus):
    """A PLC task as a clock: the master ticks it every 0.025 s (its intervalDecimal), from t = 0."""
    inst, rows = stepped(fmus["Task"], {}, ["count", "last_tick"], 10)
    for k, row in enumerate(rows):
        end = k * DT_S + DT_S  # the step's end as the master computes it; a tick is at j x 0.025
        ticks = [j * 0.025 for j in range(60) if j * 0.025 <= end]
        assert (row["count"], row["last_tick"]) == (len(ticks), ticks[-1]), end
    assert rows[-1]["count"] == 41  # t = 0, 0.025, ..., 1.0
    assert list(inst.event_times_s)[:4] == [0.025, 0.05, 0.07500000000000001, 0.1]


def test_a_clock_fishfmu_cannot_tick_is_refused_naming_it(fmus):
    from plant.errors import InputError
    with pytest.raises(InputError, match="TaskNoEventMode.fmu: clock 'tick' is a clock of an FMU without event mode"):
        with open_fmu(fmus["TaskNoEventMode"]):
            pass


@pytest.mark.parametrize("process", ["in-process", "worker"])
def test_in_a_run_the_stair_in_event_mode_sets_a_drives_setpoint(tmp_path, fmus, process):
    doc = tomllib.loads((ROOT / "scenarios" / "paper_test.toml").read_text())
    doc["run"].update(duration_s=1.0, stop_when_clear=False, fmu_process=process)
    doc["fish"]["count"] = 1
    doc["expect"] = {}
    period = 0.037  # inside the 0.01 s communication steps
    doc["fmu"].append({"name": "stair", "path": str(fmus["Stair"]), "parameters": {"period": period}})
    doc["wiring"]["connections"] = [c for c in doc["wiring"]["connections"] if "-> drive_c1.speed_setpoint" not in c]
    doc["wiring"]["connection"] = [{"from": "stair.counter", "to": "drive_c1.speed_setpoint", "gain": 0.01}]
    path = tmp_path / "stair.toml"
    path.write_text(tomli_w.dumps(doc))
    result = run_scenario(load_scenario(path), path)
    assert result.status == "ok", result.error
    s = result.signals
    counts = np.floor(s["t_s"].to_numpy() / period + 1e-9)
    assert s["stair.counter"].to_numpy() == pytest.approx(counts)
    # the stair steps before the drive (Gauss-Seidel): the drive gets each event's count in the step it fell in
    assert s["drive_c1.speed_setpoint"].to_numpy() == pytest.approx(0.01 * counts)


def test_only_periodic_input_clocks_with_a_given_interval_are_ticked():
    from fishfmu.fmu.clocks import clock_problem
    periodic = {"causality": "input", "intervalVariability": "constant", "intervalDecimal": "0.01"}
    assert clock_problem(periodic, True) is None
    assert clock_problem({**periodic, "intervalVariability": "fixed"}, True) is None
    assert "output clock" in clock_problem({**periodic, "causality": "output"}, True)
    assert "triggered" in clock_problem({"causality": "input", "intervalVariability": "triggered"}, True)
    assert "without event mode" in clock_problem(periodic, False)
    assert "interval 0" in clock_problem({**periodic, "intervalDecimal": "0"}, True)
