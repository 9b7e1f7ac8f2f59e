"""What the plant publishes after each communication step: a read-only snapshot of its state.

:class:`Plant <plant.sim.plant.Plant>` builds a :class:`PlantState` at the end of every step (and one at
rest when it is made) and exposes it as ``plant.state``.  Readers outside the plant (the energy
watch, the health checks, re-simulation) read this snapshot, never the plant's private fields.

Building it is cheap: the arrays are the plant's own arrays of that step, shared, not copied
(the plant makes new ones every step and never writes one in place after publishing it); the
snapshot holds read-only views of them, so nothing can write through it.  The one array the plant
changes in place, the fish status, is copied (one small int per fish).

>>> import numpy as np
>>> s = PlantState(t_s=0.0, fish_ids=("f1",), status=np.array([FishStatus.ON_LINE], dtype=np.int8),
...                member=np.array([0]), fish_of_body=np.zeros(5, dtype=np.int64), pos=np.zeros((5, 3)),
...                rot=np.tile(np.eye(3), (5, 1, 1)), vel=np.zeros((5, 3)), omega_local=np.zeros((5, 3)),
...                body_mass_kg=np.full(5, 0.4), body_inertia=np.zeros((5, 3)), fish_mass_kg=np.array([2.0]),
...                gravity_mps2=np.array([0.0, 0.0, -9.81]))
>>> FishStatus(s.status[0]).name, s.on_line_bodies().tolist()
('ON_LINE', [True, True, True, True, True])
>>> s.pos[0, 0] = 1.0
Traceback (most recent call last):
ValueError: assignment destination is read-only
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields

import numpy as np


class FishStatus(enum.IntEnum):
    """Where a fish is; status arrays (``Plant.status``, poses.npz ``status``) hold these as int8."""

    WAITING = 0
    """Not dropped yet (it may be in the system, parked, when its drop is due soon)."""
    ON_LINE = 1
    """Dropped and on the line."""
    LEFT = 2
    """Gone past the end of the line (or fallen off it)."""


@dataclass(frozen=True)
class PlantOutputs:
    """Sensor readings at the end of a communication step."""

    t_s: float
    belt_speed_mps: dict[str, float]
    belt_load_force_n: dict[str, float]
    belt_load_mass_kg: dict[str, float]
    photoeyes: dict[str, bool]

    def port_values(self) -> dict[str, float | bool]:
        """Every output as ``"<id>.<signal>"`` (the names connections use)."""
        out: dict[str, float | bool] = {}
        for cid in self.belt_speed_mps:
            out[f"{cid}.speed"] = self.belt_speed_mps[cid]
            out[f"{cid}.load_force"] = self.belt_load_force_n[cid]
            out[f"{cid}.load_mass"] = self.belt_load_mass_kg[cid]
        for pid, blocked in self.photoeyes.items():
            out[f"{pid}.blocked"] = blocked
        return out

    @classmethod
    def at_rest(cls, conveyor_ids: list[str], photoeye_ids: list[str], t_s: float = 0.0) -> PlantOutputs:
        """Belts stopped and unloaded, every beam clear (the outputs before the first step)."""
        return cls(t_s, dict.fromkeys(conveyor_ids, 0.0), dict.fromkeys(conveyor_ids, 0.0),
                   dict.fromkeys(conveyor_ids, 0.0), dict.fromkeys(photoeye_ids, False))


@dataclass(frozen=True)
class PlantState:
    """The plant after a communication step.  Bodies are those in the Exudyn system, fish by fish
    (slot s holds bodies ``5 s .. 5 s + 4``, head to tail); fish are indexed in the run's order."""

    t_s: float
    fish_ids: tuple[str, ...]
    """(n_fish,) every fish of the run."""
    status: np.ndarray
    """(n_fish,) int8 :class:`FishStatus` of every fish."""
    member: np.ndarray
    """(n_slots,) the fish index of each fish in the system (slot)."""
    fish_of_body: np.ndarray
    """(n_bodies,) the fish index of each body (``member`` repeated five times)."""
    pos: np.ndarray
    """(n_bodies, 3) positions of the body centres [m]."""
    rot: np.ndarray
    """(n_bodies, 3, 3) body rotation matrices (body frame to world)."""
    vel: np.ndarray
    """(n_bodies, 3) velocities [m/s]."""
    omega_local: np.ndarray
    """(n_bodies, 3) angular velocities in the body frame [rad/s]."""
    body_mass_kg: np.ndarray
    """(n_bodies,) masses."""
    body_inertia: np.ndarray
    """(n_bodies, 3) principal moments of inertia in the body frame [kg m^2]."""
    fish_mass_kg: np.ndarray
    """(n_fish,) mass of every fish."""
    gravity_mps2: np.ndarray
    """(3,) gravity vector in the line frame (x along the line, tilted by the incline)."""
    adhesion_force_n: np.ndarray | None = None
    """(n_bodies, 3) force of the ``adhesion`` extension on each body during the step; None when the
    extension is off (or before its first step)."""
    outputs: PlantOutputs | None = None
    """The sensor readings of the step (at rest before the first step)."""
    asleep: np.ndarray | None = None
    """(n_fish,) True for fish on the line carried with their belt outside the system (plant.sim.sleep);
    their bodies are not among the bodies above."""

    def __post_init__(self) -> None:
        for name in _ARRAY_FIELDS:
            value = getattr(self, name)
            if value is not None:
                view = np.asarray(value).view()
                view.setflags(write=False)
                object.__setattr__(self, name, view)

    def on_line_bodies(self) -> np.ndarray:
        """(n_bodies,) True for the bodies of fish on the line."""
        return self.status[self.fish_of_body] == FishStatus.ON_LINE


_ARRAY_FIELDS = tuple(f.name for f in fields(PlantState) if "ndarray" in str(f.type))
"""The fields :class:`PlantState` holds as read-only views."""
