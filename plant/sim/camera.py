"""A vision system over the line (``[[line.cameras]]``): what it sees of each fish, and when it says so.

What a frame holds, per fish in view (:func:`top_view`, from the bodies' poses): the fish's extent along x, from the
rearmost to the foremost point of its outline seen from above (the stadium-shaped cross-sections the photo-eyes
use), clipped to the field of view; its snout and tail tip, so its length as seen from above (a bent fish looks
shorter) and whether it comes head first (snout downstream of the tail tip).  A fish is in view when any of its
outline is between the field's edges along x (the field spans the guides across y).

When (:class:`CameraUnit`): frames at ``k / rate_hz`` (on the first plant step at or after that time; a camera
faster than the plant's steps takes one frame a step), each frame's result on the outputs ``latency_s`` later, its
positions and lengths with independent Gaussian noise of ``position_noise_m``.  From a frame:

- ``count``: fish in view; ``double``: two of them overlap along x or are closer than ``double_gap_m``;
  ``lead_double``: the leading fish has been one of such a pair in a frame since it came into view (a vision
  system classifies each tracked fish, and keeps the class: the second fish of a double is still one when the
  first has left the view; what a reject downstream acts on, the fish to come);
- the leading fish (its front end furthest downstream): ``lead_x`` its front end, ``lead_length``, ``lead_heading``
  (1 head first, -1 tail first; 0 and zero lengths with no fish in view);
- ``events``: fish seen so far (a fish counts once, the first time it is in view);
- ``results``: results given so far (steps with each new one, so that a reader knows one came).

Each frame's detections are returned as a vision system logs them (:data:`DETECTION_COLUMNS`): one row per fish in
view, named by its track number (the ``events`` count when it first came into view), not by the plant's fish id.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np

from plant.contract.line import Camera, Line
from plant.sim.equipment import Seen, Step

if TYPE_CHECKING:  # the system's outline cross-sections are read, the system is not built here
    from plant.sim.model import PlantModel

DETECTION_COLUMNS = ("t_s", "camera_id", "track", "x_back_m", "x_front_m", "y_m", "length_m", "heading", "double")
"""One row per fish in view per frame; ``t_s`` the frame's time (its result is on the outputs ``latency_s``
later)."""


@dataclass(frozen=True)
class TopView:
    """The fish on the line seen from above at one moment, arrays over those fish."""

    fish: np.ndarray
    """(n,) the fish's index in the run's list of fish."""
    x_back_m: np.ndarray
    """(n,) rearmost point of the outline along x."""
    x_front_m: np.ndarray
    """(n,) foremost point of the outline along x."""
    y_m: np.ndarray
    """(n,) mid-length point across the line."""
    snout_xy: np.ndarray
    """(n, 2) snout tip."""
    tail_xy: np.ndarray
    """(n, 2) tail tip."""


def top_view(fish_of_section: np.ndarray, centres: np.ndarray, axes: np.ndarray, half_len: np.ndarray,
             radius: np.ndarray, fish: np.ndarray, snout: np.ndarray, tail: np.ndarray, mid: np.ndarray) -> TopView:
    """What a camera sees of ``fish`` (n,) from their outlines' cross-sections: section ``i`` belongs to the
    ``fish_of_section[i]``-th of them (0..n-1), a capsule ``centres[i] +- s axes[i]`` (|s| <= ``half_len[i]``)
    thickened by ``radius[i]``; ``snout``, ``tail``, ``mid`` (n, 3) their spine points."""
    n = len(fish)
    reach = np.abs(axes[:, 0]) * half_len + radius  # a capsule's half extent along x
    back, front = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(back, fish_of_section, centres[:, 0] - reach)
    np.maximum.at(front, fish_of_section, centres[:, 0] + reach)
    return TopView(np.asarray(fish), back, front, mid[:, 1].copy(), snout[:, :2].copy(), tail[:, :2].copy())


def fish_seen_from_above(model: PlantModel, pos: np.ndarray, rot: np.ndarray, slots: np.ndarray, fish: np.ndarray,
                         tips: tuple[np.ndarray, np.ndarray], mids: tuple[np.ndarray, np.ndarray]) -> TopView:
    """:func:`top_view` of the fish in the system's ``slots`` (``fish`` their indices in the run), from the bodies'
    positions ``pos`` and rotations ``rot`` and the system's outline cross-sections; ``tips`` the (slots, 2) bodies
    holding each fish's snout and tail tip and those points in their frames, ``mids`` the same (slots, 1) for the
    mid-length point."""
    nb = model.bodies_per_fish
    sel = np.flatnonzero(np.isin(model.section_body // nb, slots))
    b = model.section_body[sel]
    r = rot[b]
    centres = pos[b] + r[:, :, 0] * model.section_x[sel][:, None]

    def points(bodies: np.ndarray, local: np.ndarray, j: int) -> np.ndarray:
        return pos[bodies[:, j]] + np.einsum("nij,nj->ni", rot[bodies[:, j]], local[:, j])

    return top_view(np.searchsorted(slots, b // nb), centres, r[:, :, 1], model.section_half_len[sel],
                    model.section_radius[sel], fish, points(*tips, 0), points(*tips, 1), points(*mids, 0))


@dataclass(frozen=True)
class Reading:
    """What a camera's outputs say (the result of one frame)."""

    count: int = 0
    double: bool = False
    lead_double: bool = False
    lead_x_m: float = 0.0
    lead_length_m: float = 0.0
    lead_heading: int = 0
    events: int = 0
    results: int = 0
    """Results given so far, this one included: it steps with every new result (a PLC's cue to read one)."""


class CameraUnit:
    """One camera: takes frames of :class:`TopView` at its rate and gives each frame's :class:`Reading` after its
    latency.  ``rng`` draws its noise (seeded by the caller)."""

    def __init__(self, camera: Camera, rng: np.random.Generator) -> None:
        self.camera = camera
        self.rng = rng
        self.frames = 0
        self.reading = Reading()
        self._pending: deque[tuple[float, Reading]] = deque()
        self._track: dict[int, int] = {}
        """Fish index -> its track number (the events count when it was first in view)."""
        self._doubled: set[int] = set()
        """Fish seen as one of a double in some frame."""

    def frame_due(self, t_s: float) -> bool:
        return t_s + 1e-9 >= self.frames / self.camera.rate_hz

    def take_frame(self, t_s: float, view: TopView) -> list[tuple]:
        """A frame of ``view`` at ``t_s``, its result on the outputs from ``t_s + latency_s``; returns its
        detections (rows of :data:`DETECTION_COLUMNS`)."""
        cam = self.camera
        while self.frames / cam.rate_hz <= t_s + 1e-9:  # frames missed between two steps are not taken
            self.frames += 1
        seen = (view.x_front_m > cam.x_start_m) & (view.x_back_m < cam.x_end_m)
        k = np.flatnonzero(seen)
        noise = cam.position_noise_m
        back = np.clip(view.x_back_m[k], cam.x_start_m, cam.x_end_m) + self.rng.normal(0.0, noise, len(k))
        front = np.clip(view.x_front_m[k], cam.x_start_m, cam.x_end_m) + self.rng.normal(0.0, noise, len(k))
        y = view.y_m[k] + self.rng.normal(0.0, noise, len(k))
        whole = (view.x_back_m[k] >= cam.x_start_m) & (view.x_front_m[k] <= cam.x_end_m)
        tips = np.linalg.norm(view.snout_xy[k] - view.tail_xy[k], axis=1)
        # a fish partly out of view is as long as the part that is in it
        length = np.where(whole, tips, np.maximum(front - back, 0.0)) + self.rng.normal(0.0, noise, len(k))
        heading = np.where(view.snout_xy[k, 0] >= view.tail_xy[k, 0], 1, -1)
        order = np.argsort(back)
        double = bool(len(k) > 1 and np.any(back[order][1:] - np.maximum.accumulate(front[order])[:-1]
                                             < cam.double_gap_m))
        for f in view.fish[k]:
            self._track.setdefault(int(f), len(self._track) + 1)
        lead = int(np.argmax(front)) if len(k) else -1
        apart = np.maximum(back[:, None] - front[None, :], back[None, :] - front[:, None])  # each pair's gap
        np.fill_diagonal(apart, np.inf)
        self._doubled.update(int(f) for f in view.fish[k][np.any(apart < cam.double_gap_m, axis=1)])
        lead_double = bool(len(k) and int(view.fish[k][lead]) in self._doubled)
        reading = Reading(len(k), double, lead_double, float(front[lead]) if len(k) else 0.0,
                          float(length[lead]) if len(k) else 0.0, int(heading[lead]) if len(k) else 0,
                          len(self._track), self.frames)
        self._pending.append((t_s + cam.latency_s, reading))
        return [(round(t_s, 6), cam.id, self._track[int(f)], float(back[i]), float(front[i]), float(y[i]),
                 float(length[i]), int(heading[i]), double) for i, f in enumerate(view.fish[k])]

    def output(self, t_s: float) -> Reading:
        """The outputs at ``t_s``: the result of the last frame whose latency has passed."""
        while self._pending and self._pending[0][0] <= t_s + 1e-9:
            self.reading = self._pending.popleft()[1]
        return self.reading


def output_fields(readings: dict[str, Reading]) -> dict[str, dict]:
    """The cameras' readings (by camera id) as the :class:`~plant.sim.state.PlantOutputs` fields that hold them."""
    return {"camera_count": {i: r.count for i, r in readings.items()},
            "camera_double": {i: r.double for i, r in readings.items()},
            "camera_lead_double": {i: r.lead_double for i, r in readings.items()},
            "camera_lead_x_m": {i: r.lead_x_m for i, r in readings.items()},
            "camera_lead_length_m": {i: r.lead_length_m for i, r in readings.items()},
            "camera_lead_heading": {i: r.lead_heading for i, r in readings.items()},
            "camera_events": {i: r.events for i, r in readings.items()},
            "camera_results": {i: r.results for i, r in readings.items()}}


class Cameras:
    """Every camera of the line in the plant's step (:mod:`plant.sim.equipment`): the fish seen from above only when
    one of them takes a frame; the frames' detections of the last step in :attr:`detections`."""

    def __init__(self, units: list[CameraUnit]) -> None:
        self.units = units
        self.detections: tuple[tuple, ...] = ()

    @classmethod
    def of(cls, line: Line, seed: int) -> Cameras:
        # each camera's noise its own stream of the run's seed: adding a camera changes no other's
        return cls([CameraUnit(c, np.random.default_rng([seed, 7, i])) for i, c in enumerate(line.cameras)])

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None:
        pass  # a camera acts on nothing

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]:
        t = step.t_end_s
        due = [c for c in self.units if c.frame_due(t)]
        view = seen.top_view() if due else None
        self.detections = tuple(row for c in due for row in c.take_frame(t, view))
        return output_fields({c.camera.id: c.output(t) for c in self.units})

    def takes(self, mid_m: np.ndarray, on: np.ndarray) -> None:
        return None

    def published(self) -> dict:
        return {"detections": self.detections}
