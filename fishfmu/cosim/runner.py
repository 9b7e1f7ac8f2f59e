"""Running a scenario: build the plant and the FMUs, wire them, step the master, compute the KPIs.

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
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from plant.errors import SimulationError
from plant.kpis import compute_kpis
from plant.measured import Run
from plant.plant import Plant
from plant.population import FishSpec, fish_to_frame, sample_fish
from plant.recorder import RunRecorder, pose_record
from plant.simulate import run_loop

from fishfmu.fmu.archive import OpenedFmu, open_fmu
from fishfmu.cosim.interrupt import StopRequest
from fishfmu.cosim.master import CoSimulation, setpoint_sources, signal_frame, signal_names
from fishfmu.cosim.preflight import FmuDescription, describe, preflight
from fishfmu.cosim.results import ExpectResult, RunResult  # noqa: F401 (re-exported)
from fishfmu.scenario.schema import Scenario


def scenario_fish(scenario: Scenario) -> list[FishSpec]:
    """The batch of a scenario: sampled from its seed (the same seed gives the same fish)."""
    rng = np.random.default_rng([scenario.run.seed, scenario.fish.seed_offset])
    first = scenario.line.conveyors[0]
    return sample_fish(scenario.fish, (first.x_start_m, first.x_end_m), 0.5 * scenario.line.guide_width_m, rng)


def fmu_path(instance) -> Path:
    if instance.builtin is not None:
        from fishfmu.fmu.build import builtin_fmu
        return builtin_fmu(instance.builtin)
    return Path(instance.path)


def check_scenario(scenario: Scenario, scenario_file: str | Path | None = None) -> None:
    """Everything a run checks before it starts, without running: each FMU file opens and is valid,
    its parameters exist and fit, and the wiring resolves (raises InputError naming what is wrong)."""
    with contextlib.ExitStack() as stack:
        opened = {f.name: stack.enter_context(open_fmu(fmu_path(f))) for f in scenario.fmu}
        preflight(scenario, scenario_file, _described(opened))


def _described(opened: dict[str, OpenedFmu]) -> dict[str, FmuDescription]:
    return {n: describe(o.path, o.model_description, o.variables) for n, o in opened.items()}


def run_scenario(scenario: Scenario, scenario_file: str | Path | None = None,
                 on_progress: Callable[[float, float], None] | None = None,
                 fish: list[FishSpec] | None = None, record_poses: bool = False,
                 stop: StopRequest | None = None) -> RunResult:
    """Run one scenario; a failure inside the run is returned as ``status = "failed"`` with what was
    recorded until then (bad input is raised as InputError before anything runs).  When ``stop`` is
    requested (a signal, see :mod:`fishfmu.cosim.interrupt`) the run ends after the current step with
    ``status = "partial"``."""
    fish = scenario_fish(scenario) if fish is None else fish
    sfile = str(scenario_file) if scenario_file else None
    timings = {"setup": 0.0}
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        opened = {f.name: stack.enter_context(open_fmu(fmu_path(f))) for f in scenario.fmu}
        wiring = preflight(scenario, sfile, _described(opened))
        plant = Plant(scenario.line, fish, scenario.plant, scenario.run.comm_step_s)
        recorder = RunRecorder([f.fish_id for f in fish], plant.conveyor_ids, plant.photoeye_ids,
                               scenario.run.comm_step_s, record_poses=record_poses)
        status, error = "ok", None
        cosim: CoSimulation | None = None
        try:  # an FMU failing while it is instantiated and initialised fails the run, as in any step
            fmus = _instantiate(scenario, opened, stack)
            cosim = CoSimulation(plant, fmus, {f.name: f.step_multiple for f in scenario.fmu}, wiring,
                                 scenario.event, scenario.run.comm_step_s, jacobi=scenario.run.coupling == "jacobi",
                                 recorder=recorder, setpoint_sources=setpoint_sources(wiring, plant.conveyor_ids))
        except SimulationError as exc:
            status, error = "failed", str(exc)
        else:
            stack.callback(cosim.terminate)
        timings["setup"] = time.perf_counter() - t0
        t_run = time.perf_counter()
        if cosim is not None:
            try:
                _loop(cosim, scenario, on_progress, stop)
            except SimulationError as exc:
                status, error = "failed", str(exc)
            except _Stopped as exc:
                status, error = "partial", str(exc)
        wall = time.perf_counter() - t_run
        if cosim is None or cosim.steps == 0:
            _record_start(recorder, plant, cosim)
        tables = recorder.tables()
        run = Run(id=scenario.run.name.replace(" ", "_"), hours_post_mortem=scenario.fish.hours_post_mortem,
                  notes=f"simulated: seed {scenario.run.seed}", fish=fish_to_frame(fish), tracks=tables["tracks"],
                  photoeyes=tables["photoeyes"], belts=tables["belts"])
        kpis = compute_kpis(run, scenario.line, scenario.kpi)
        expect = [ExpectResult(k, _number(kpis.get(k)), b.min, b.max) for k, b in scenario.expect.items()]
        if cosim is None:
            signals, t_end, worst = signal_frame([], signal_names(wiring)), 0.0, (0.0, 0.0)
        else:
            watch = cosim.energy_watch
            signals, t_end, worst = cosim.signal_frame(), cosim.t_s, (watch.worst_excess_j, watch.worst_ratio)
        return RunResult(scenario, fish, run, kpis, signals, expect, status, error, t_end, wall,
                         timings, list(plant.drop_adjustments), pose_record(recorder, plant),
                         {"worst_excess_j": worst[0], "worst_fraction_of_reserve": worst[1]})


def _record_start(recorder: RunRecorder, plant: Plant, cosim: CoSimulation | None) -> None:
    """Record the line as it was at t = 0 for a run that failed before completing a step (an FMU
    failing while initialised or in its first step): belts at rest, each setpoint as the FMUs gave
    it after initialisation (the belt speed where there is none), fish where they are, no beam
    blocked.  The run then is a valid measured-data run of one sample, as any partial run."""
    speeds = {c: 0.0 for c in plant.conveyor_ids}
    values = cosim.values if cosim is not None else {}
    sources = cosim.setpoint_sources if cosim is not None else {}
    setpoints = {}
    for c, v in speeds.items():
        sp = values.get(sources.get(c, ""), v)
        setpoints[c] = float(sp) if isinstance(sp, (int, float)) and np.isfinite(sp) else v
    recorder.record(0.0, plant.fish_state, {p: False for p in plant.photoeye_ids}, setpoints, speeds,
                    plant.body_poses)


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _instantiate(scenario: Scenario, opened, stack: contextlib.ExitStack) -> dict[str, Any]:
    from fishfmu.fmu.instance import FmuInstance
    fmus = {}
    for f in scenario.fmu:
        if scenario.run.fmu_process == "worker":
            from fishfmu.fmu.worker import WorkerFmu
            fmus[f.name] = WorkerFmu(f.name, opened[f.name], f.parameters, scenario.run.fmu_step_timeout_s)
        else:
            fmus[f.name] = FmuInstance(f.name, opened[f.name], f.parameters)
        stack.callback(fmus[f.name].terminate)  # also when a later one fails to start
    return fmus


class _Stopped(Exception):
    """The run was asked to stop (a signal)."""


def _loop(cosim: CoSimulation, scenario: Scenario, on_progress: Callable[[float, float], None] | None,
          stop: StopRequest | None = None) -> None:
    def check_stop() -> None:
        if stop is not None and stop.requested:
            raise _Stopped(f"interrupted by {stop.signal_name} at t = {cosim.t_s:.3f} s, before the end "
                           f"({scenario.run.duration_s:g} s)")

    run_loop(cosim.step, lambda: cosim.t_s, lambda: cosim.plant.status, scenario.run.duration_s,
             scenario.run.comm_step_s, stop_when_clear=scenario.run.stop_when_clear, clear_margin_s=1.0,
             before_step=check_stop, on_progress=on_progress)
