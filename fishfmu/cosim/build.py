"""What a run is built from, built once: the checked scenario, then the co-simulation.

Two steps, because bad input must be found before anything is written and a failing FMU must still
leave a written run:

1. :func:`checked` opens (unpacks and checks) every FMU archive once, describes it and runs the
   :func:`~fishfmu.cosim.preflight.preflight` checks; what it yields (:class:`CheckedScenario`) holds
   the opened FMUs and the resolved wiring until the ``with`` ends.  Bad input raises InputError.
2. :func:`build` makes the plant, the recorder and the FMU instances from it and yields the
   :class:`~fishfmu.cosim.master.CoSimulation` that owns them; leaving the ``with`` terminates every
   FMU.  An FMU failing while it is instantiated or initialised raises :class:`BuildFailed`, which
   carries the plant and the recorder so that the run can still be written (a failed run at t = 0).

>>> with checked(scenario) as c, build(c, scenario_fish(scenario)) as sim:  # doctest: +SKIP
...     sim.step()
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plant.contract.parts import part_triangles
from plant.errors import InputError, SimulationError
from plant.sim.observers import StepObserver
from plant.sim.plant import Plant
from plant.sim.ports import PlantPorts
from plant.fish.population import FishSpec, lane_across, sample_fish
from plant.sim.recorder import RunRecorder

from fishfmu.cosim.master import NO_CLOCK, CoSimulation, StageClock
from fishfmu.cosim.preflight import describe, preflight
from fishfmu.fmu.archive import OpenedFmu, open_fmu
from fishfmu.fmu.build import builtin_fmu
from fishfmu.fmu.instance import InProcessFmu
from fishfmu.fmu.worker import WorkerFmu
from fishfmu.scenario.schema import FmuInstance as FmuEntry, Scenario
from fishfmu.scenario.wiring import Wiring


def scenario_fish(scenario: Scenario) -> list[FishSpec]:
    """The batch of a scenario: sampled from its seed (the same seed gives the same fish)."""
    rng = np.random.default_rng([scenario.run.seed, scenario.fish.seed_offset])
    first = scenario.line.conveyors[0]
    # dropped within the guides wherever on the infeed: the lane between them all along it (an off-centre one too)
    centre_y_m, half_width_m = lane_across(*scenario.line.guide_y_at(np.linspace(first.x_start_m, first.x_end_m, 51)))
    return sample_fish(scenario.fish, (first.x_start_m, first.x_end_m), half_width_m, rng, centre_y_m)


def fmu_path(fmu: FmuEntry) -> Path:
    """The FMU file a scenario's ``[[fmu]]`` names: a built-in one (built or taken from the cache) or a path."""
    if fmu.builtin is not None:
        return builtin_fmu(fmu.builtin)
    return Path(fmu.path)


def as_the_user_names_it(fmu: FmuEntry, exc: InputError) -> InputError:
    """An error about an FMU's file, naming the file as the user knows it: for a component of ``[system] ssp``,
    the SSP and the component with its source there (its ``path`` is fishfmu's copy in the cache)."""
    if fmu.ssp_source is None:
        return exc
    ssp, source = fmu.ssp_source
    where = f" ({exc.where})" if exc.where else ""
    return InputError(f"component '{fmu.name}' (source '{source}'): {exc.message}{where}", file=ssp)


@contextlib.contextmanager
def opened_fmu(fmu: FmuEntry) -> Iterator[OpenedFmu]:
    """:func:`~fishfmu.fmu.archive.open_fmu` of a scenario's FMU; its errors name it as the user does."""
    with contextlib.ExitStack() as stack:
        try:
            opened = stack.enter_context(open_fmu(fmu_path(fmu)))
        except InputError as exc:
            raise as_the_user_names_it(fmu, exc) from None
        yield opened


@dataclass(frozen=True)
class CheckedScenario:
    """A scenario whose FMUs are open (unpacked, checked) and whose parameters and wiring passed."""

    scenario: Scenario
    scenario_file: str | None
    opened: dict[str, OpenedFmu]
    wiring: Wiring


@contextlib.contextmanager
def checked(scenario: Scenario, scenario_file: str | Path | None = None) -> Iterator[CheckedScenario]:
    """Open every FMU once and check everything a run checks before it starts (raises InputError);
    the unpacked FMUs are removed when the ``with`` ends."""
    sfile = str(scenario_file) if scenario_file else None
    part_triangles(scenario.line)  # the parts' STL files are read as the plant will read them
    with contextlib.ExitStack() as stack:
        opened = {f.name: stack.enter_context(opened_fmu(f)) for f in scenario.fmu}
        described = {n: describe(o.path, o.model_description, o.variables) for n, o in opened.items()}
        yield CheckedScenario(scenario, sfile, opened, preflight(scenario, sfile, described))


def check_scenario(scenario: Scenario, scenario_file: str | Path | None = None) -> None:
    """Everything a run checks before it starts, without running (raises InputError naming what is wrong)."""
    with checked(scenario, scenario_file):
        pass


class BuildFailed(SimulationError):
    """An FMU failed while it was instantiated or initialised; the plant and recorder are as at t = 0."""

    def __init__(self, error: SimulationError, plant: Plant, recorder: RunRecorder) -> None:
        super().__init__(str(error))
        self.plant, self.recorder = plant, recorder


def instantiate(scenario: Scenario, opened: dict[str, OpenedFmu], stack: contextlib.ExitStack) -> dict[str, Any]:
    """One instance per ``[[fmu]]``, in-process or in a worker process as ``run.fmu_process`` says;
    each is terminated when ``stack`` closes, also when a later one fails to start."""
    fmus = {}
    for f in scenario.fmu:
        try:
            if scenario.run.fmu_process == "worker":
                fmus[f.name] = WorkerFmu(f.name, opened[f.name], f.parameters, scenario.run.fmu_step_timeout_s)
            else:
                fmus[f.name] = InProcessFmu(f.name, opened[f.name], f.parameters)
        except InputError as exc:  # a binary that does not load
            raise as_the_user_names_it(f, exc) from None
        stack.callback(fmus[f.name].terminate)
    return fmus


@contextlib.contextmanager
def build(checked_scenario: CheckedScenario, fish: list[FishSpec], record_poses: bool = False,
          clock: StageClock = NO_CLOCK, observers: Sequence[StepObserver] = ()) -> Iterator[CoSimulation]:
    """The co-simulation of a checked scenario with this batch of fish; it owns the plant and the FMU
    instances (terminated when the ``with`` ends).  ``clock`` times the stages of each step (benchmarks);
    ``observers`` are attached after those every way of stepping attaches (:mod:`plant.sim.observers`)."""
    sc = checked_scenario.scenario
    plant = Plant(sc.line, fish, sc.plant, sc.run.comm_step_s, seed=sc.run.seed)
    ports = PlantPorts.of(sc.line)
    recorder = RunRecorder([f.fish_id for f in fish], list(ports.conveyor_ids), list(ports.photoeye_ids),
                           sc.run.comm_step_s, ports.device_ids, record_poses=record_poses)
    wiring = checked_scenario.wiring
    with contextlib.ExitStack() as stack:
        try:
            fmus = instantiate(sc, checked_scenario.opened, stack)
            cosim = CoSimulation(plant, ports, fmus, {f.name: f.step_multiple for f in sc.fmu}, wiring, sc.event,
                                 sc.run.comm_step_s, jacobi=sc.run.coupling == "jacobi", recorder=recorder,
                                 clock=clock, outfeed=sc.kpi.outfeed_photoeye, observers=list(observers))
        except SimulationError as exc:
            raise BuildFailed(exc, plant, recorder) from exc
        yield cosim
