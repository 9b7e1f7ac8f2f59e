"""What watches the plant's step: the one step loop's observers (libcosim's observers are the example).

Every way the line is stepped (the plant alone, :func:`plant.sim.simulate.simulate_plant`; a co-simulation,
``fishfmu.cosim.master``, which ``fishfmu run`` and ``fishfmu serve`` step; the plant as an FMU,
``fishfmu.cosim.plant_fmu``) steps the plant and then hands each observer the state it published, in the order
attached. :func:`plant_watches` is the set each of them attaches: the energy watch first (a blow-up raises
SimulationError there, before anything records the step) and the fish counts.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol

import numpy as np

from plant.sim.health import EnergyWatch
from plant.sim.state import FishStatus, PlantOutputs, PlantState


class StepObserver(Protocol):
    """Called after every plant step with what the plant published; raises SimulationError to stop the run."""

    def after_step(self, state: PlantState, outputs: PlantOutputs, dt_s: float) -> None: ...


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

    def after_step(self, state: PlantState, outputs: PlantOutputs, dt_s: float) -> None:
        status = state.status
        waiting = int(np.count_nonzero(status == FishStatus.WAITING))
        self.values.update(fish_waiting=waiting, fish_dropped=len(status) - waiting,
                           fish_on_line=int(np.count_nonzero(status == FishStatus.ON_LINE)),
                           fish_left=int(np.count_nonzero(status == FishStatus.LEFT)),
                           fish_rejected=int(np.count_nonzero(status == FishStatus.REJECTED)))
        if self.outfeed is not None:
            blocked = bool(outputs.photoeyes[self.outfeed])
            if blocked and not self._was_blocked:
                self.values["outfeed_count"] += 1
            self._was_blocked = blocked


def plant_watches(outfeed: str | None = None) -> tuple[EnergyWatch, FishCounts]:
    """The observers every way of stepping the plant attaches: the energy watch, then the fish counts."""
    return EnergyWatch(), FishCounts(outfeed)


def notify(observers: Iterable[StepObserver], state: PlantState, outputs: PlantOutputs, dt_s: float) -> None:
    """Hand one step's published state to each observer, in order (the first to raise stops the rest)."""
    for observer in observers:
        observer.after_step(state, outputs, dt_s)
