"""What the plant publishes after each communication step: a read-only snapshot of its state.

:class:`Plant <plant.sim.plant.Plant>` builds a :class:`PlantState` at the end of every step (and one at
rest when it is made) and exposes it as ``plant.state``; its step returns the state's sensor readings
(:class:`PlantOutputs`).  That is all readers outside the plant read (the co-simulation, the energy watch,
the recorder, the plant FMU, ``fishfmu serve``, re-simulation): the fish's status and poses
(:meth:`PlantState.fish_poses`, :meth:`PlantState.body_poses`), the drops the plant raised, its timings.

Building it is cheap: the arrays are the plant's own arrays of that step, shared, not copied
(the plant makes new ones every step and never writes one in place after publishing it); the
snapshot holds read-only views of them (or the arrays themselves, where the plant made them read-only), so nothing
can write through it.  The one array the plant changes in place, the fish status, is copied (one small int per
fish).

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
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, make_dataclass
from types import MappingProxyType

import numpy as np

from plant.fish.fish_body import FishGeometry
from plant.sim.ports import KINDS, SIGNALS, PlantPorts


class FishStatus(enum.IntEnum):
    """Where a fish is; status arrays (``Plant.status``, poses.npz ``status``) hold these as int8."""

    WAITING = 0
    """Not dropped yet (it may be in the system, parked, when its drop is due soon)."""
    ON_LINE = 1
    """Dropped and on the line."""
    LEFT = 2
    """Gone past the end of the line (or fallen off it)."""
    REJECTED = 3
    """Taken off the line by one of its devices (a gate, pusher or diverter)."""


def _port_values(self: PlantOutputs) -> Mapping[str, float | bool]:
    """Every output as ``"<id>.<signal>"`` (the names connections use), in the order of
    :meth:`PlantPorts.outputs <plant.sim.ports.PlantPorts.outputs>`; read-only, worked out once (a step's
    outputs are read by the master, its recording and its observers)."""
    if (done := self.__dict__.get("_port_values_done")) is not None:
        return MappingProxyType(done)
    out: dict[str, float | bool] = {}
    for of in KINDS:
        signals = [(s.name, getattr(self, s.field)) for s in OUTPUT_SIGNALS if s.of == of]
        for i in (signals[0][1] if signals else ()):  # each field holds every unit of its kind, by id
            for name, values in signals:
                out[f"{i}.{name}"] = values[i]
    object.__setattr__(self, "_port_values_done", out)  # frozen: kept beside the fields, not one of them
    return MappingProxyType(out)


def _at_rest(cls: type, ports: PlantPorts, t_s: float = 0.0) -> PlantOutputs:
    """Belts stopped and unloaded, every beam clear, every camera with nothing seen, every device home (the outputs
    before the first step: each signal's ``rest_value``)."""
    return cls(t_s, **{s.field: dict.fromkeys(ports.ids_of(s.of), s.rest_value) for s in OUTPUT_SIGNALS})


OUTPUT_SIGNALS = tuple(s for s in SIGNALS.values() if s.is_output)

PlantOutputs = make_dataclass(
    "PlantOutputs", [("t_s", float)] + [(s.field, dict, field(default_factory=dict)) for s in OUTPUT_SIGNALS],
    frozen=True, namespace={"port_values": _port_values, "at_rest": classmethod(_at_rest)})
PlantOutputs.__module__ = __name__  # make_dataclass's module= is Python 3.12's
PlantOutputs.__doc__ = """Sensor readings at the end of a communication step: ``t_s`` and, for each output signal of the
ports table (:data:`plant.sim.ports.SIGNALS`), a field named by its ``field`` holding its value by unit id (the
class is built from that table: a new signal is a row there, not a field here)."""


@dataclass(frozen=True)
class StepInputs:
    """What a plant step was given, by id: each belt's speed and each device's command (the plant's inputs), and
    each belt's setpoint as belts.csv logs it (its drive's target in a co-simulation; the speed itself where the
    speed is given directly)."""

    belt_speed_mps: dict[str, float]
    device_commands: dict[str, bool]
    belt_setpoint_mps: dict[str, float]


@dataclass
class FishState:
    """Poses of all fish at the end of a step (measured-data frame): NaN for fish not on the line."""

    t_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    yaw_rad: np.ndarray
    status: np.ndarray
    """:class:`FishStatus` (int8) of every fish."""


@dataclass(frozen=True)
class DropAdjustment:
    """A fish dropped higher than asked, to clear the fish already on the line below it."""

    fish_id: str
    raised_by_m: float


@dataclass(frozen=True)
class PlantState:
    """The plant after a communication step.  Bodies are those in the Exudyn system, fish by fish
    (slot s holds bodies ``nb s .. nb s + nb - 1``, head to tail, nb = ``bodies_per_fish``); fish are indexed in the
    run's order."""

    t_s: float
    fish_ids: tuple[str, ...]
    """(n_fish,) every fish of the run."""
    status: np.ndarray
    """(n_fish,) int8 :class:`FishStatus` of every fish."""
    member: np.ndarray
    """(n_slots,) the fish index of each fish in the system (slot)."""
    fish_of_body: np.ndarray
    """(n_bodies,) the fish index of each body (``member`` repeated ``bodies_per_fish`` times)."""
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
    pose_bodies: np.ndarray | None = None
    """(n_slots, 3) the bodies holding each fish's spine points at 50, 20 and 80 % of its length."""
    pose_local: np.ndarray | None = None
    """(n_slots, 3, 3) those points in their bodies' frames."""
    geometry: tuple[FishGeometry, ...] = ()
    """(n_fish,) every fish's bodies (to draw them: their outlines)."""
    drop_adjustments: tuple[DropAdjustment, ...] = ()
    """Every drop so far that the plant raised to clear the fish below."""
    detections: tuple[tuple, ...] = ()
    """The cameras' detections of the frames taken in this step (rows of
    :data:`plant.sim.camera.DETECTION_COLUMNS`; empty in a step without a frame)."""
    rejected_by: np.ndarray | None = None
    """(n_fish,) index of the device (in the line's order) that took each fish off the line, -1 for none."""
    device_position: np.ndarray | None = None
    """(n_devices,) every device's position along its travel (0 home, 1 at its end)."""
    device_work_j: float = 0.0
    """Work the devices did on the fish during the step [J] (a source of their energy, like the belts)."""
    timings_s: dict[str, float] = field(default_factory=dict)
    """Wall time spent so far in Exudyn's solver (``exudyn``) and in rebuilding the system (``rebuild``; the longest
    rebuild: ``rebuild_longest``, a step's worth of time at once when serving in real time)."""
    body_on: np.ndarray | None = None
    """(n_bodies,) True for the bodies of fish on the line (:meth:`on_line_bodies`; worked out from the status when
    not given)."""

    def __post_init__(self) -> None:
        for name in _ARRAY_FIELDS:
            value = getattr(self, name)
            if value is not None and (not isinstance(value, np.ndarray) or value.flags.writeable):  # else read-only
                view = np.asarray(value).view()
                view.setflags(write=False)
                object.__setattr__(self, name, view)

    @property
    def bodies_per_fish(self) -> int:
        """Bodies of every fish of the run: 5 for the paper's fish, 4 for the joined one (``plant.fish_model``)."""
        return len(self.geometry[0].bodies) if self.geometry else 5

    def on_line_bodies(self) -> np.ndarray:
        """(n_bodies,) True for the bodies of fish on the line."""
        if self.body_on is not None:
            return self.body_on
        return self.status[self.fish_of_body] == FishStatus.ON_LINE

    def fish_poses(self) -> FishState:
        """Mid-length point and heading of every fish on the line (NaN for the others).

        The heading is that of the chord from the spine point at 80 % of the length to the one at
        20 %: what an overhead camera sees as the fish's direction, robust to a wagging head or tail.
        """
        n = len(self.fish_ids)
        x, y, z, yaw = (np.full(n, np.nan) for _ in range(4))
        slots = np.flatnonzero(self.status[self.member] == FishStatus.ON_LINE)
        if len(slots):
            b = self.pose_bodies[slots]  # (m, 3): bodies holding the 50 %, 20 %, 80 % points
            pts = self.pos[b] + np.einsum("mkij,mkj->mki", self.rot[b], self.pose_local[slots])
            chord = pts[:, 1] - pts[:, 2]
            k = self.member[slots]
            x[k], y[k], z[k] = pts[:, 0, 0], pts[:, 0, 1], pts[:, 0, 2]
            yaw[k] = np.arctan2(chord[:, 1], chord[:, 0])
        return FishState(self.t_s, x, y, z, yaw, self.status.copy())

    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (nb n_fish, 3), rotation matrices (nb n_fish, 3, 3)) of every fish's bodies, in the
        run's fish order; NaN for fish not in the system (waiting or gone)."""
        nb = self.bodies_per_fish
        n = nb * len(self.fish_ids)
        pos = np.full((n, 3), np.nan)
        rot = np.full((n, 3, 3), np.nan)
        body_index = (nb * self.fish_of_body + np.tile(np.arange(nb), len(self.member))) if len(self.member) else []
        pos[body_index] = self.pos
        rot[body_index] = self.rot
        return pos, rot


_ARRAY_FIELDS = tuple(f.name for f in fields(PlantState) if "ndarray" in str(f.type))
"""The fields :class:`PlantState` holds as read-only views."""
