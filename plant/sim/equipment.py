"""The line's equipment in the plant's step, behind one small interface: belts, photo-eyes, cameras and devices.

Each kind is one object holding every unit of that kind (numpy over the units, not a Python object per unit), and
the plant runs them all alike (:func:`plant.sim.plant.equipment_of` makes them, in the order they run):

- ``before_solve(step, q, v)``: what it does to the system before Exudyn integrates the step (belts and devices put
  their bodies at their poses, moving at the step's rate, in the system's coordinate and velocity vectors);
- ``after_solve(step, seen)``: what it reads after the integration: its :class:`~plant.sim.state.PlantOutputs`
  fields (the ports table's ``field`` of each of its signals, :mod:`plant.sim.ports`), by unit id;
- ``takes(mid_m, on)``: the fish it takes off the line, per fish in the system (the unit's index, -1 for none);
- ``published()``: what it adds to the step's :class:`~plant.sim.state.PlantState` beyond its outputs.

A new kind of equipment is then its own module with one such class, its signals in the ports table and its entry
in the line description (``plant.contract.line``), and a line in :func:`plant.sim.plant.equipment_of`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from plant.sim.model import PlantModel


@dataclass(frozen=True)
class Step:
    """One communication step as the equipment sees it, from its start."""

    t_end_s: float
    dt_s: float
    model: PlantModel
    """The Exudyn system of the step (rebuilt when fish come and go)."""
    belt_speeds_mps: np.ndarray
    """(n_conveyors,) the belts' speeds for the step, in the line's order."""
    device_commands: np.ndarray
    """(n_devices,) True: to the end of its travel; False: home."""


@dataclass(frozen=True)
class Seen:
    """The system after the step's integration, as the equipment reads it."""

    pos: np.ndarray
    """(n_bodies, 3) the fish bodies' centres."""
    rot: np.ndarray
    """(n_bodies, 3, 3) their rotation matrices."""
    body_on: np.ndarray
    """(n_bodies,) True for the bodies of fish on the line."""
    velocities: np.ndarray
    """The system's ODE2 velocity vector (belt and device bodies read their own entries)."""
    top_view: Callable[[], object]
    """The fish on the line seen from above (a :class:`plant.sim.camera.TopView`), worked out when called: only a
    camera taking a frame needs it."""
    rejected_by: np.ndarray
    """(n_fish,) the index of the device that took each fish off the line, -1 for none."""


class Equipment(Protocol):
    """One kind of the line's equipment (every unit of it)."""

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None: ...

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]: ...

    def takes(self, mid_m: np.ndarray, on: np.ndarray) -> np.ndarray | None: ...

    def published(self) -> dict: ...

