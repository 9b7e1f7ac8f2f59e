"""The devices' actuators in the plant: where each device is along its travel, and its body in the Exudyn system.

An actuator moves at constant speed (its whole travel in ``stroke_s``, as a pneumatic cylinder with its flow set by
a throttle does) towards the end its command asks for, and stops there.  It is position-controlled: it keeps that
speed whatever the fish push back with (no force limit: a gate closing on a fish lifts it, a paddle pushes a jam).
Like a belt body, a device body is put at its pose at the start of every communication step and given the step's
rate; it carries its triangles (the shapes of :mod:`plant.contract.devices`) through the step, and what the fish
push on it shows as its momentum change.

>>> from plant.contract.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "devices": [{"id": "p", "kind": "pusher", "x_m": 0.5, "length_m": 0.8, "stroke_s": 0.1}]})
>>> act = DeviceActuators.of(line)
>>> [round(float(act.advance(np.array([True]), 0.03)[0]), 2) for _ in range(5)]   # 0.3 of the travel a step
[0.3, 0.6, 0.9, 1.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plant.contract.devices import DeviceShape, device_shapes, exits
from plant.contract.line import Line
from plant.sim.equipment import Seen, Step
from plant.sim.model import BELT_MASS_KG



@dataclass
class DeviceActuators:
    """Every device's actuator: positions (0 home, 1 end of travel) and the rate of the step under way; the devices
    in the plant's step (:mod:`plant.sim.equipment`)."""

    line: Line
    ids: tuple[str, ...]
    shapes: tuple[DeviceShape, ...]
    stroke_s: np.ndarray
    position: np.ndarray
    """(n,) at the end of the last step."""
    start: np.ndarray
    """(n,) at the start of the step under way."""
    rate_per_s: np.ndarray
    """(n,) d position / dt during the step under way."""
    set_velocity: list[np.ndarray] = field(default_factory=list)
    """Each body's velocity and angular velocity (6,) as :meth:`place` set them for the step under way."""
    work_j: float = 0.0
    """What :meth:`work_on_fish_j` last returned."""

    @classmethod
    def of(cls, line: Line) -> DeviceActuators:
        n = len(line.devices)
        return cls(line, tuple(d.id for d in line.devices), device_shapes(line),
                   np.array([d.stroke_s for d in line.devices], dtype=float), np.zeros(n), np.zeros(n), np.zeros(n))

    def commands(self, device_commands: dict[str, bool] | None) -> np.ndarray:
        """(n,) the step's commands in the line's order: True to the end of the travel; a device not named (or all,
        with None) home; a name the line has no device for is a KeyError."""
        if device_commands and (unknown := sorted(set(device_commands) - set(self.ids))):
            raise KeyError(f"no device named {', '.join(unknown)} (devices: {', '.join(self.ids)})")
        return np.array([bool((device_commands or {}).get(i, False)) for i in self.ids], dtype=bool)

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None:
        """Each actuator a step further towards its command, its body put at its pose at the step's start."""
        if not self.ids:  # a line without devices: nothing to move (their numpy would cost 0.07 ms a step)
            return
        self.advance(step.device_commands, step.dt_s)
        self.place(q, v, step.model.device_ltg, step.belt_speeds_mps, step.dt_s)

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]:
        if not self.ids:
            return {}
        self.work_on_fish_j(seen.velocities[step.model.device_ltg], BELT_MASS_KG)
        return self.output_fields(self.ids, seen.rejected_by)

    def takes(self, mid_m: np.ndarray, on: np.ndarray) -> np.ndarray | None:
        """Per fish in the system (its mid point ``mid_m`` (n, 3), ``on`` the line): the device through whose exit
        it has gone, -1 for none."""
        if not self.shapes:
            return None
        return np.where(on, exits(self.shapes, self.line, mid_m[:, 0], mid_m[:, 1], mid_m[:, 2]), -1)

    def published(self) -> dict:
        return {"device_position": self.position, "device_work_j": self.work_j}

    def advance(self, commands: np.ndarray, dt_s: float) -> np.ndarray:
        """Start a step of ``dt_s`` with each device commanded to its end (True) or home (False); returns the
        positions at the step's end."""
        self.start = self.position
        reach = dt_s / self.stroke_s
        self.position = self.start + np.clip(np.asarray(commands, dtype=float) - self.start, -reach, reach)
        self.rate_per_s = (self.position - self.start) / dt_s
        return self.position

    def place(self, q: np.ndarray, v: np.ndarray, ltg: np.ndarray, belt_speeds_mps: np.ndarray, dt_s: float) -> None:
        """Write each device body's coordinates (relative to its home pose, the node's reference) and velocities
        for the step's start into the system's ODE2 vectors ``q`` and ``v``; a gate's surface runs at the speed of
        the belt before it (its body shifted back half a step of that travel, as a belt's is)."""
        self.set_velocity = []
        for i, shape in enumerate(self.shapes):
            p = float(self.start[i])
            origin, rotvec = shape.pose(p)
            surface = float(belt_speeds_mps[shape.feeder]) if shape.feeder >= 0 else 0.0
            vel, omega = shape.velocity(p, float(self.rate_per_s[i]), surface)
            if surface:
                origin = origin - 0.5 * dt_s * shape.velocity(p, 0.0, surface)[0]
            q[ltg[i]] = np.concatenate([origin - shape.origin_m, rotvec])
            v[ltg[i]] = np.concatenate([vel, omega])
            self.set_velocity.append(v[ltg[i]].copy())

    def work_on_fish_j(self, v_end: np.ndarray, mass_kg: float) -> float:
        """Work the devices did on the fish over the step [J]: minus what the fish did on the device bodies, whose
        velocities (``v_end``, (n, 6): velocity, angular velocity) the fish changed from those set by :meth:`place`."""
        total = 0.0
        for i, set_v in enumerate(self.set_velocity):
            total -= mass_kg * float(np.dot(v_end[i] - set_v, set_v))  # the body's inertia is mass_kg about every axis
        self.work_j = total
        return total

    def output_fields(self, ids: tuple[str, ...], rejected_by: np.ndarray) -> dict[str, dict]:
        """The devices' :class:`~plant.sim.state.PlantOutputs` fields by device id (``ids`` in the line's order), with
        ``rejected_by`` the device index that took each fish off the line (-1: none)."""
        counts = np.bincount(rejected_by[rejected_by >= 0], minlength=len(ids))
        return {"device_position": dict(zip(ids, map(float, self.position))),
                "device_at_home": {i: bool(p <= 0.0) for i, p in zip(ids, self.position)},
                "device_at_end": {i: bool(p >= 1.0) for i, p in zip(ids, self.position)},
                "device_rejected": dict(zip(ids, map(int, counts)))}
