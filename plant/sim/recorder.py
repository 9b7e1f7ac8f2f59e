"""Recording a simulated run in the measured-data format (contracts/measured-data.md).

The same four tables a line's instruments give: fish tracks at 25 Hz (mid-length point and heading, like the
overhead camera), photo-eye blocked intervals, and belt setpoints and speeds at 100 Hz; and the logs a line with
cameras and devices gives: the cameras' detections, the devices' rejections (one row per fish a device took off, at
the end of the step in which the plant found it gone) and their commands (every device's at the start, then a row at
each change, at the start of the step that took it: :mod:`plant.contract.device_commands`).  A simulated run written this way goes through exactly the
readers and KPI code that a measured one does.

Photo-eye interval times are the ends of the communication steps at which the beam was first
seen blocked and first seen clear again (resolution: one communication step).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import BELTS, DETECTIONS, DEVICE_COMMANDS, PHOTOEYES, REJECTIONS, TRACKS
from plant.sim.rotations import matrix_to_quaternion
from plant.sim.state import FishStatus, PlantState, StepInputs

TRACK_PERIOD_S = 0.04
BELT_PERIOD_S = 0.01


@dataclass
class RunRecorder:
    """Collects samples step by step; ``tables()`` returns the contract's tables."""

    fish_ids: list[str]
    conveyor_ids: list[str]
    photoeye_ids: list[str]
    comm_step_s: float
    device_ids: tuple[str, ...] = ()
    _tracks: list[tuple] = field(default_factory=list)
    _rejections: list[tuple] = field(default_factory=list)
    _rejected_by: np.ndarray | None = None
    _commands: list[tuple] = field(default_factory=list)
    _last_command: dict[str, bool] = field(default_factory=dict)
    _device_position: list[np.ndarray] = field(default_factory=list)
    _belts: list[tuple] = field(default_factory=list)
    _intervals: list[tuple[str, float, float]] = field(default_factory=list)
    _detections: list[tuple] = field(default_factory=list)
    _blocked_since: dict[str, float | None] = field(default_factory=dict)
    _last_track_t: float = -1.0
    _last_belt_t: float = -1.0
    _t_last: float = 0.0
    record_poses: bool = False
    """Also keep every body's pose at the track rate (for the 3D replay)."""
    _pose_t: list[float] = field(default_factory=list)
    _pose_pos: list[np.ndarray] = field(default_factory=list)
    _pose_quat: list[np.ndarray] = field(default_factory=list)
    _pose_status: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._blocked_since = {p: None for p in self.photoeye_ids}

    def record(self, state: PlantState, inputs: StepInputs) -> None:
        """One communication step: the state the plant published at its end (its outputs, fish and body poses only
        when a sample is due, the cameras' detections, the devices' rejections and positions) and what the step was
        given (belt setpoints and speeds; device commands, logged where they changed, at the step's start)."""
        t_s, photoeyes, rejected_by = state.t_s, state.outputs.photoeyes, state.rejected_by
        self._detections.extend(state.detections)
        for d, on in inputs.device_commands.items():
            if self._last_command.get(d) != bool(on):
                self._commands.append((self._t_last, d, int(bool(on))))
                self._last_command[d] = bool(on)
        if rejected_by is not None and self.device_ids:
            before = self._rejected_by if self._rejected_by is not None else np.full(len(rejected_by), -1)
            for k in np.flatnonzero(rejected_by != before):
                self._rejections.append((t_s, self.device_ids[int(rejected_by[k])], self.fish_ids[k]))
            self._rejected_by = rejected_by
        eps = 1e-9
        if t_s - self._last_track_t >= TRACK_PERIOD_S - eps:
            self._last_track_t = t_s
            fish = state.fish_poses()
            for k in np.flatnonzero(fish.status == FishStatus.ON_LINE):
                self._tracks.append((t_s, self.fish_ids[k], fish.x_m[k], fish.y_m[k], fish.yaw_rad[k]))
            if self.record_poses:
                pos, rot = state.body_poses()
                self._pose_t.append(t_s)
                self._pose_pos.append(pos.astype(np.float32))
                self._pose_quat.append(matrix_to_quaternion(rot).astype(np.float32))
                self._pose_status.append(fish.status.copy())
                if self.device_ids:
                    self._device_position.append(np.asarray(state.device_position, dtype=np.float32))
        if t_s - self._last_belt_t >= BELT_PERIOD_S - eps:
            self._last_belt_t = t_s
            for c in self.conveyor_ids:
                self._belts.append((t_s, c, inputs.belt_setpoint_mps[c], inputs.belt_speed_mps[c]))
        for p, blocked in photoeyes.items():
            since = self._blocked_since[p]
            if blocked and since is None:
                self._blocked_since[p] = t_s
            elif not blocked and since is not None:
                self._intervals.append((p, since, t_s))
                self._blocked_since[p] = None
        self._t_last = t_s

    def poses(self) -> dict[str, np.ndarray] | None:
        """Body poses at the track rate: ``t_s`` (F,), ``pos`` (F, B, 3), ``quat`` (F, B, 4: w, x, y, z),
        ``status`` (F, n_fish) of :class:`plant.sim.state.FishStatus` (int8), and with devices ``device_id`` (D,) and
        ``device_position`` (F, D); None unless ``record_poses``."""
        if not self.record_poses:
            return None
        # every fish's bodies, as many as the fish model has (none recorded yet: the paper's five)
        n_b = len(self._pose_pos[0]) if self._pose_pos else 5 * len(self.fish_ids)
        devices = ({"device_id": np.array(list(self.device_ids)),
                    "device_position": np.array(self._device_position, dtype=np.float32).reshape(-1, len(self.device_ids))}
                   if self.device_ids else {})
        return devices | {"t_s": np.array(self._pose_t),
                "pos": np.array(self._pose_pos, dtype=np.float32).reshape(-1, n_b, 3),
                "quat": np.array(self._pose_quat, dtype=np.float32).reshape(-1, n_b, 4),
                "status": np.array(self._pose_status, dtype=np.int8).reshape(-1, len(self.fish_ids))}

    def tables(self) -> dict[str, pd.DataFrame]:
        """tracks, photoeyes, belts, detections, rejections and device_commands tables (the last None on a line without
        devices); a beam still blocked at the end closes at the last time."""
        intervals = list(self._intervals) + [(p, s, self._t_last) for p, s in self._blocked_since.items()
                                             if s is not None]
        intervals.sort(key=lambda r: (r[1], r[0]))
        # a device never commanded in a recorded step (a run that failed before its first) was home from the start
        commands = [(0.0, d, 0) for d in self.device_ids if d not in self._last_command] + self._commands
        return {
            "tracks": pd.DataFrame(self._tracks, columns=list(TRACKS.columns)),
            "photoeyes": pd.DataFrame(intervals, columns=list(PHOTOEYES.columns)),
            "belts": pd.DataFrame(self._belts, columns=list(BELTS.columns)),
            "detections": pd.DataFrame([(*r[:-1], int(r[-1])) for r in self._detections],
                                       columns=list(DETECTIONS.columns)),
            "rejections": pd.DataFrame(self._rejections, columns=list(REJECTIONS.columns)),
            "device_commands": pd.DataFrame(commands, columns=list(DEVICE_COMMANDS.columns))
            if self.device_ids else None,
        }


def pose_record(recorder: RunRecorder, state: PlantState) -> dict[str, np.ndarray] | None:
    """The recorder's body poses plus what is needed to draw the bodies (the arrays of a run folder's
    poses.npz, see fishfmu.output.replay), from the plant's published ``state``; None unless the recorder
    keeps poses.

    ``body_fish`` (B,) fish index of each body, ``fish_id`` (N,), ``section_body``/``section_x``/
    ``section_half_height``/``section_half_width`` (S,): each body's outline as cross-sections along
    its local x axis (local y towards the back, local z the thickness).  Plain numpy arrays: they
    pickle, so re-simulations in worker processes can return them.
    """
    poses = recorder.poses()
    if poses is None:
        return None
    poses.update(body_outlines(state))
    return poses


def body_outlines(state: PlantState) -> dict[str, np.ndarray]:
    """What is needed to draw the bodies of every fish (the arrays of poses.npz besides the poses): ``fish_id``,
    ``body_fish`` and the outlines as cross-sections (``section_*``, see :func:`pose_record`)."""
    body, x, half_h, half_w = [], [], [], []
    for k, geometry in enumerate(state.geometry):
        for i, b in enumerate(geometry.bodies):
            for (sx, hh, hw) in b.outline:
                body.append(state.bodies_per_fish * k + i)
                x.append(sx)
                half_h.append(hh)
                half_w.append(hw)
    return {
        "fish_id": np.array(list(state.fish_ids)),
        "body_fish": np.repeat(np.arange(len(state.fish_ids)), state.bodies_per_fish).astype(np.int32),
        "section_body": np.array(body, dtype=np.int32),
        "section_x": np.array(x, dtype=np.float32),
        "section_half_height": np.array(half_h, dtype=np.float32),
        "section_half_width": np.array(half_w, dtype=np.float32),
    }
