"""Running a scenario: check it, build the co-simulation, step it to the end, collect the result.

>>> from fishfmu.cosim.runner import run_scenario                       # doctest: +SKIP
>>> from fishfmu.scenario.schema import load_scenario                    # doctest: +SKIP
>>> sc = load_scenario("scenarios/paper_test.toml")               # doctest: +SKIP
>>> sc.fish.count = 12                                            # doctest: +SKIP
>>> result = run_scenario(sc)                                     # doctest: +SKIP
>>> result.kpis["singulation_rate"], result.signals.columns[:3]   # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from plant.errors import SimulationError
from plant.contract.kpis import compute_kpis
from plant.contract.measured import Run
from plant.sim.observers import StepInputs, StepObserver
from plant.sim.plant import Plant
from plant.sim.state import PlantState
from plant.contract.measured import fish_to_frame
from plant.fish.population import FishSpec
from plant.sim.recorder import RunRecorder, pose_record
from plant.sim.simulate import RunEnd, run_loop

from fishfmu.cosim.build import BuildFailed, CheckedScenario, build, checked, scenario_fish
from fishfmu.cosim.stop import StopRequest
from fishfmu.cosim.master import NO_CLOCK, CoSimulation, StageClock, setpoint_value, signal_frame
from fishfmu.cosim.results import ExpectResult, RunResult
from fishfmu.scenario.schema import Bound, Scenario
from fishfmu.scenario.wiring import signal_names


def run_scenario(scenario: Scenario, scenario_file: str | Path | None = None,
                 on_progress: Callable[[float, float], None] | None = None,
                 fish: list[FishSpec] | None = None, record_poses: bool = False,
                 stop: StopRequest | None = None, checked_scenario: CheckedScenario | None = None,
                 clock: StageClock = NO_CLOCK, observers: Sequence[StepObserver] = ()) -> RunResult:
    """Run one scenario; a failure inside the run is returned as ``status = "failed"`` with what was
    recorded until then (bad input is raised as InputError before anything runs).  When ``stop`` is
    requested (a signal, see :mod:`fishfmu.cosim.stop`) the run ends after the current step with
    ``status = "partial"``.  ``checked_scenario`` is the scenario already checked with its FMUs open
    (:func:`fishfmu.cosim.build.checked`, as ``fishfmu run`` does before it writes anything).  ``observers``: step
    observers attached after the energy watch, the fish counts and the recording (:mod:`plant.sim.observers`)."""
    fish = scenario_fish(scenario) if fish is None else fish
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if checked_scenario is None:
            checked_scenario = stack.enter_context(checked(scenario, scenario_file))
        try:
            cosim = stack.enter_context(build(checked_scenario, fish, record_poses, clock, observers))
        except BuildFailed as exc:  # an FMU failing while instantiated and initialised fails the run
            failed = collect(scenario, fish, exc.plant, exc.recorder, None, "failed", str(exc),
                             {"setup": time.perf_counter() - t0}, 0.0, signal_names(checked_scenario.wiring))
            failed.wiring = checked_scenario.wiring.describe()
            return failed
        timings = {"setup": time.perf_counter() - t0}
        t_run = time.perf_counter()
        status, error = "ok", None
        try:
            _loop(cosim, scenario, on_progress, stop)
        except SimulationError as exc:
            status, error = "failed", str(exc)
        except _Stopped as exc:
            status, error = "partial", str(exc)
        result = collect(scenario, fish, cosim.plant, cosim.recorder, cosim, status, error, timings,
                         time.perf_counter() - t_run)
    result.wiring = checked_scenario.wiring.describe()
    return result


def collect(scenario: Scenario, fish: list[FishSpec], plant: Plant, recorder: RunRecorder,
            cosim: CoSimulation | None, status: str, error: str | None, timings_s: dict[str, float],
            wall_s: float, signal_columns: list[str] | None = None) -> RunResult:
    """The result of a run from what it recorded: the run in the measured-data format, KPIs,
    ``[expect]`` outcomes, signals, energy check.  ``cosim`` is None when the FMUs never started
    (``signal_columns`` then names the columns of the empty signal table)."""
    state = plant.state
    if cosim is None or cosim.steps == 0:
        _record_start(recorder, state, cosim)
    tables = recorder.tables()
    run = Run(id=scenario.run.name.replace(" ", "_"), hours_post_mortem=scenario.fish.hours_post_mortem,
              notes=f"simulated: seed {scenario.run.seed}", fish=fish_to_frame(fish), tracks=tables["tracks"],
              photoeyes=tables["photoeyes"], belts=tables["belts"], detections=tables["detections"],
              rejections=tables["rejections"], device_commands=tables["device_commands"])
    kpis = compute_kpis(run, scenario.line, scenario.kpi)
    if cosim is None:
        signals, t_end, worst = signal_frame([], signal_columns or []), 0.0, (0.0, 0.0)
    else:
        watch = cosim.energy_watch
        signals, t_end, worst = cosim.signal_frame(), cosim.t_s, (watch.worst_excess_j, watch.worst_ratio)
    expect = [ExpectResult(k, _number(kpis.get(k)), b.min, b.max) for k, b in scenario.expect.items() if "." not in k]
    for k, b in scenario.expect.items():
        if "." in k:
            expect += signal_expectations(k, b, signals)
    timings_s = {**timings_s, **{f"plant_{k}": v for k, v in state.timings_s.items()}}
    return RunResult(scenario, fish, run, kpis, signals, expect, status, error, t_end, wall_s,
                     timings_s, list(state.drop_adjustments), pose_record(recorder, state),
                     {"worst_excess_j": worst[0], "worst_fraction_of_reserve": worst[1]})


def _record_start(recorder: RunRecorder, state: PlantState, cosim: CoSimulation | None) -> None:
    """Record the line as it was at t = 0 for a run that failed before completing a step (an FMU
    failing while initialised or in its first step): belts at rest, each setpoint as the FMUs gave
    it after initialisation (the belt speed where there is none), fish where they are, no beam
    blocked.  The run then is a valid measured-data run of one sample, as any partial run."""
    speeds = {c: 0.0 for c in recorder.conveyor_ids}
    values = cosim.values if cosim is not None else {}
    sources = cosim.setpoint_sources if cosim is not None else {}
    constants = cosim.wiring.constants if cosim is not None else {}
    setpoints = {}
    for c, v in speeds.items():
        sp = setpoint_value(sources.get(c), constants, values, v)
        setpoints[c] = float(sp) if isinstance(sp, (int, float)) and np.isfinite(sp) else v
    recorder.record(state, StepInputs(speeds, {}, setpoints))  # the state at rest: no beam blocked


def signal_expectations(key: str, bound: Bound, signals: pd.DataFrame) -> list[ExpectResult]:
    """A recorded signal's bounds as checks: its lowest value against ``min``, its highest against ``max``, its last
    against ``final`` +- ``tolerance`` (a signal not recorded in this run, or a run without steps: undefined)."""
    values = signals[key].astype(float).to_numpy() if key in signals and len(signals) else np.zeros(0)
    has = len(values) > 0
    out = []
    if bound.min is not None:
        out.append(ExpectResult(f"{key} (lowest)", float(values.min()) if has else None, bound.min, None))
    if bound.max is not None:
        out.append(ExpectResult(f"{key} (highest)", float(values.max()) if has else None, None, bound.max))
    if bound.final is not None:
        out.append(ExpectResult(f"{key} (final)", float(values[-1]) if has else None,
                                bound.final - bound.tolerance, bound.final + bound.tolerance))
    return out


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


CLEAR_MARGIN_S = 1.0
"""With ``run.stop_when_clear``, a run ends this long after the last fish has left the line."""


def run_end(scenario: Scenario) -> RunEnd:
    """Where a run of ``scenario`` ends by itself: its duration, or (``stop_when_clear``) CLEAR_MARGIN_S after the last
    fish has left; ``fishfmu run``'s end and ``fishfmu serve``'s."""
    return RunEnd(scenario.run.duration_s, scenario.run.comm_step_s, scenario.run.stop_when_clear, CLEAR_MARGIN_S)


class _Stopped(Exception):
    """The run was asked to stop (a signal)."""


def _loop(cosim: CoSimulation, scenario: Scenario, on_progress: Callable[[float, float], None] | None,
          stop: StopRequest | None = None) -> None:
    def check_stop() -> None:
        if stop is not None and stop.requested:
            raise _Stopped(f"interrupted by {stop.signal_name} at t = {cosim.t_s:.3f} s, before the end "
                           f"({scenario.run.duration_s:g} s)")

    run_loop(cosim.step, lambda: cosim.t_s, lambda: cosim.plant.state.status, run_end(scenario),
             before_step=check_stop, on_progress=on_progress)
