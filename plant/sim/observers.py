"""What watches the plant's step: the one step loop's observers (libcosim's observers are the example).

Every way the line is stepped (the plant alone, :func:`plant.sim.simulate.simulate_plant`; a co-simulation,
``fishfmu.cosim.master``, which ``fishfmu run`` and ``fishfmu serve`` step; the plant as an FMU,
``fishfmu.cosim.plant_fmu``) steps the plant and then hands each observer, in the order attached, the state it
published, its outputs, what the step was given (:class:`StepInputs`: only the one who stepped the plant knows the
belts' setpoints) and the step's length.  :func:`plant_observers` is the set each of them attaches, made in this one
place: the energy watch first (a blow-up raises SimulationError there, before anything records the step), the fish
counts, then the recording of the run in the measured-data format where there is a recorder (the plant FMU has
none: its host records).  Anything attached after them (a script's own, ``fishfmu serve``'s publication) sees the
step once it is counted and recorded.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol

import numpy as np

from plant.sim.health import EnergyWatch
from plant.sim.recorder import RunRecorder
from plant.sim.state import FishStatus, PlantOutputs, PlantState, StepInputs  # noqa: F401 (StepInputs: theirs too)


class StepObserver(Protocol):
    """Called after every plant step with what the plant published and what it was given; raises SimulationError
    to stop the run."""

    def after_step(self, state: PlantState, outputs: PlantOutputs, inputs: StepInputs, dt_s: float) -> None: ...


class FishCounts:
    """The fish counted after each step, under the one set of names every way of serving uses (``fish_<name>``):
    ``waiting`` (not yet dropped), ``dropped`` (all but waiting), ``on_line``, ``left`` (gone past the end or off
    the line), ``rejected`` (taken off by a device), and ``outfeed_count``: fish heads seen at the ``outfeed``
    photo-eye (its blocked edges; 0 without one)."""

    NAMES = ("fish_waiting", "fish_dropped", "fish_on_line", "fish_left", "fish_rejected", "outfeed_count")

    def __init__(self, outfeed: str | None = None) -> None:
        self.outfeed = outfeed
        self.values = dict.fromkeys(self.NAMES, 0)
        self._was_blocked = False

    def after_step(self, state: PlantState, outputs: PlantOutputs, inputs: StepInputs, dt_s: float) -> None:
        status = state.status
        n = np.bincount(status, minlength=len(FishStatus))  # fish of each status, in one pass
        waiting = int(n[FishStatus.WAITING])
        self.values.update(fish_waiting=waiting, fish_dropped=len(status) - waiting,
                           fish_on_line=int(n[FishStatus.ON_LINE]), fish_left=int(n[FishStatus.LEFT]),
                           fish_rejected=int(n[FishStatus.REJECTED]))
        if self.outfeed is not None:
            blocked = bool(outputs.photoeyes[self.outfeed])
            if blocked and not self._was_blocked:
                self.values["outfeed_count"] += 1
            self._was_blocked = blocked


class Recording:
    """Records each step into ``recorder`` (:class:`plant.sim.recorder.RunRecorder`: the run in the measured-data
    format) from the published state and the step's inputs: fish tracks and body poses when due, photo-eyes, belt
    setpoints and speeds, the cameras' detections, the devices' rejections, positions and commands."""

    def __init__(self, recorder: RunRecorder) -> None:
        self.recorder = recorder

    def after_step(self, state: PlantState, outputs: PlantOutputs, inputs: StepInputs, dt_s: float) -> None:
        self.recorder.record(state, inputs)


def plant_observers(outfeed: str | None = None, recorder: RunRecorder | None = None) -> list[StepObserver]:
    """The observers every way of stepping the plant attaches, in order: the energy watch, the fish counts
    (``outfeed``: the photo-eye whose blocked edges they count), and the recording into ``recorder`` if any."""
    return [EnergyWatch(), FishCounts(outfeed), *([Recording(recorder)] if recorder is not None else [])]


def notify(observers: Iterable[StepObserver], state: PlantState, outputs: PlantOutputs, inputs: StepInputs,
           dt_s: float) -> None:
    """Hand one step's published state and inputs to each observer, in order (the first to raise stops the rest)."""
    for observer in observers:
        observer.after_step(state, outputs, inputs, dt_s)
