"""The belts in the plant's step (:mod:`plant.sim.equipment`): the speed each runs at, and the load it carries.

A belt is a body under the line's belt surface (:mod:`plant.sim.model`): put back at its place at the start of
every communication step, shifted back half a step of travel, and given the step's speed along its slope, so that
its surface carries the fish; what the fish push on it over the step shows as its momentum change, read as the load
(:func:`plant.sim.sensors.belt_loads`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plant.contract.line import Line
from plant.errors import SimulationError
from plant.sim.equipment import Seen, Step
from plant.sim.model import BELT_MASS_KG
from plant.sim.sensors import belt_loads



@dataclass(frozen=True)
class Belts:
    """Every conveyor's belt: its id and the (cos, sin) of its incline, in the line's order."""

    ids: tuple[str, ...]
    direction: np.ndarray
    """(n, 2) (cos, sin) of each belt's incline: the direction it carries along x and z."""
    gravity_mps2: float

    @classmethod
    def of(cls, line: Line, gravity_mps2: float) -> Belts:
        a = np.radians([c.incline_deg for c in line.conveyors])
        return cls(tuple(c.id for c in line.conveyors), np.array([[np.cos(x), np.sin(x)] for x in a]).reshape(-1, 2),
                   gravity_mps2)

    def speeds(self, belt_speeds_mps: dict[str, float] | np.ndarray, t_s: float) -> np.ndarray:
        """The step's speeds as an array in the line's order (by id, or an array already in that order); a missing
        belt is a KeyError, a speed that is not a number a SimulationError at ``t_s``."""
        if isinstance(belt_speeds_mps, dict):
            missing = [c for c in self.ids if c not in belt_speeds_mps]
            if missing:
                raise KeyError(f"no speed given for conveyor(s) {', '.join(missing)}")
            speeds = np.array([float(belt_speeds_mps[c]) for c in self.ids])
        else:
            speeds = np.asarray(belt_speeds_mps, dtype=float).reshape(len(self.ids))
        if not np.all(np.isfinite(speeds)):
            raise SimulationError(f"belt speed is not a number: {dict(zip(self.ids, speeds))}", t_s)
        return speeds

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None:
        """Each belt body back at its place, shifted back half a step of travel, moving at its speed along its slope."""
        ltg = step.model.belt_ltg
        q[ltg] = 0.0
        v[ltg] = 0.0
        for axis, share in ((0, self.direction[:, 0]), (2, self.direction[:, 1])):
            q[ltg[:, axis]] = -0.5 * step.belt_speeds_mps * step.dt_s * share
            v[ltg[:, axis]] = step.belt_speeds_mps * share

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]:
        ltg = step.model.belt_ltg
        vel_end = seen.velocities[ltg[:, :3]] if len(ltg) else np.zeros((0, 3))
        load, mass = belt_loads(vel_end, step.belt_speeds_mps, BELT_MASS_KG, step.dt_s, self.gravity_mps2,
                                self.direction)
        return {"belt_speed_mps": dict(zip(self.ids, map(float, step.belt_speeds_mps))),
                "belt_load_force_n": dict(zip(self.ids, map(float, load))),
                "belt_load_mass_kg": dict(zip(self.ids, map(float, mass)))}

    def takes(self, mid_m: np.ndarray, on: np.ndarray) -> None:
        return None  # a belt carries fish off the line's end; the plant retires those itself

    def published(self) -> dict:
        return {}
