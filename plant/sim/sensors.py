"""What the plant measures, computed from the body states of one communication step.

- photo-eyes: a beam across the line (along y) at (x, z) is blocked when it passes through a
  fish's body, taken from its outline (a stadium-shaped cross-section every centimetre), not from
  the coarser contact spheres, whose valleys would let a beam through a fish; an eye with a latency
  reports that state that much later (:class:`BeamDelay`);
- belt load: the force the fish put on a belt along x and down, from the belt body's momentum
  change over the step (nothing else acts on it);
- where on each fish's spine its tracked points are (:func:`spine_point_local`; the poses themselves:
  :meth:`plant.sim.state.PlantState.fish_poses`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from plant.contract.line import Line
from plant.fish.fish_body import FishGeometry
from plant.sim.equipment import Seen, Step

if TYPE_CHECKING:  # the system's outline cross-sections are read, the system is not built here
    from plant.sim.model import PlantModel


def sphere_centres(body_pos: np.ndarray, body_rot: np.ndarray, sphere_body: np.ndarray,
                   sphere_local: np.ndarray) -> np.ndarray:
    """World positions (n_spheres, 3) of all contact spheres."""
    return body_pos[sphere_body] + np.einsum("nij,nj->ni", body_rot[sphere_body], sphere_local)


def photoeyes_blocked(section_centres: np.ndarray, section_axes: np.ndarray, half_len: np.ndarray,
                      radius: np.ndarray, beams_xz: np.ndarray, span_y_m: np.ndarray,
                      pairs: np.ndarray | None = None) -> np.ndarray:
    """(n_beams,) True where a beam at (x, z), spanning y from ``span_y_m[:, 1]`` to ``span_y_m[:, 0]`` (between
    the guides there: (left, right) per beam), cuts a fish cross-section.

    A cross-section is a capsule: the segment ``centre +- s * axis`` (|s| <= half_len, axis = the
    body's dorsal direction) thickened by ``radius``.  The beam runs along y, so only the distance
    in the x-z plane counts: minimise it over s (a quadratic) and compare with the radius.  ``pairs``
    (n_beams, n_sections), when given: only these (beam, cross-section) pairs are looked at.
    """
    if len(beams_xz) == 0 or len(section_centres) == 0:
        return np.zeros(len(beams_xz), dtype=bool)
    c, u = section_centres, section_axes
    dx = c[None, :, 0] - beams_xz[:, None, 0]
    dz = c[None, :, 2] - beams_xz[:, None, 1]
    uu = u[:, 0] ** 2 + u[:, 2] ** 2
    s = -(dx * u[None, :, 0] + dz * u[None, :, 2]) / np.where(uu > 1e-12, uu, 1.0)[None, :]
    s = np.clip(s, -half_len[None, :], half_len[None, :])
    ex = dx + s * u[None, :, 0]
    ez = dz + s * u[None, :, 2]
    y = c[None, :, 1] + s * u[None, :, 1]
    span = np.asarray(span_y_m, dtype=float).reshape(-1, 2)
    hit = ((ex * ex + ez * ez < radius[None, :] ** 2) & (y < span[:, :1] + radius[None, :])
           & (y > span[:, 1:] - radius[None, :]))
    if pairs is not None:
        hit &= pairs
    return hit.any(axis=1)


def outline_reach_m(model: PlantModel) -> float:
    """The farthest any point of a body's outline lies from the body's centre along any direction (its
    cross-section's offset along the body, half its length and its radius): a body whose centre is farther than
    this from a beam along x cannot cut it."""
    if len(model.section_body) == 0:
        return 0.0
    return float(np.max(np.abs(model.section_x) + model.section_half_len + model.section_radius))


def beams_blocked(model: PlantModel, pos: np.ndarray, rot: np.ndarray, body_on: np.ndarray, beams_xz: np.ndarray,
                  span_y_m: np.ndarray, reach_m: float | None = None) -> np.ndarray:
    """(n_beams,) True where a beam cuts the outline of a body of a fish on the line (``body_on``), from the
    bodies' positions and rotations.  Each beam is tested only against the bodies near it: those whose centre
    lies within ``reach_m`` (:func:`outline_reach_m`, worked out when not given) of it along x."""
    if len(beams_xz) == 0 or len(model.section_body) == 0:
        return np.zeros(len(beams_xz), dtype=bool)
    reach = (outline_reach_m(model) if reach_m is None else reach_m) + 1e-9  # 1e-9: rounding of the centres
    near = body_on[:, None] & (np.abs(pos[:, :1] - beams_xz[None, :, 0]) < reach)  # (bodies, beams)
    sel = np.flatnonzero(np.any(near, axis=1)[model.section_body])
    if not len(sel):
        return np.zeros(len(beams_xz), dtype=bool)
    b = model.section_body[sel]
    r = rot[b]
    centres = pos[b] + r[:, :, 0] * model.section_x[sel][:, None]
    return photoeyes_blocked(centres, r[:, :, 1], model.section_half_len[sel], model.section_radius[sel], beams_xz,
                             span_y_m, near[b].T)


class BeamDelay:
    """Each photo-eye's blocked signal as it is reported: ``latency_s`` late (an input filter, a slow input card),
    in whole communication steps (rounded to the nearest; at least half a step rounds up to one).  Both edges are
    delayed alike, so a blocked interval keeps its length; before the first step's state has come through, a delayed
    eye reports clear, like the line at rest."""

    def __init__(self, latency_s: list[float], comm_step_s: float) -> None:
        self.steps = np.array([int(np.floor(lat / comm_step_s + 0.5 + 1e-9)) for lat in latency_s], dtype=np.int64)
        self._past = np.zeros((int(self.steps.max(initial=0)) + 1, len(latency_s)), dtype=bool)  # ring of states
        self._now = 0

    def __call__(self, blocked: np.ndarray) -> np.ndarray:
        """The states reported after this step, given the beams' states now."""
        if not self.steps.any():
            return blocked
        self._now = (self._now + 1) % len(self._past)
        self._past[self._now] = blocked
        return self._past[(self._now - self.steps) % len(self._past), np.arange(len(self.steps))]


class PhotoEyes:
    """Every photo-eye of the line in the plant's step (:mod:`plant.sim.equipment`): each beam from guide to guide at
    its (x, z), blocked by the outlines of the fish on the line, reported after its latency."""

    def __init__(self, ids: tuple[str, ...], beams_xz: np.ndarray, span_y_m: np.ndarray, delay: BeamDelay) -> None:
        self.ids, self.beams_xz, self.span_y_m, self.delay = ids, beams_xz, span_y_m, delay
        self._model, self._reach_m = None, 0.0  # the system the reach was worked out for

    @classmethod
    def of(cls, line: Line, comm_step_s: float) -> PhotoEyes:
        beams = np.array([[p.x_m, p.z_m] for p in line.photoeyes]).reshape(-1, 2)
        return cls(tuple(p.id for p in line.photoeyes), beams, np.column_stack(line.guide_y_at(beams[:, 0])),
                   BeamDelay([p.latency_s for p in line.photoeyes], comm_step_s))

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None:
        pass  # a beam acts on nothing

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]:
        if step.model is not self._model:  # once per system: it changes only when the plant rebuilds it
            self._model, self._reach_m = step.model, outline_reach_m(step.model)
        blocked = beams_blocked(step.model, seen.pos, seen.rot, seen.body_on, self.beams_xz, self.span_y_m,
                                self._reach_m)
        return {"photoeyes": dict(zip(self.ids, map(bool, self.delay(blocked))))}

    def takes(self, mid_m: np.ndarray, on: np.ndarray) -> None:
        return None

    def published(self) -> dict:
        return {}


def belt_loads(vel_end: np.ndarray, speed_set_mps: np.ndarray, mass_kg: float, dt_s: float,
               gravity_mps2: float, direction: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(load force along the belt opposing it [N], mass resting on the belt [kg]: its normal force / g) per belt.

    ``vel_end``: (n_belts, 3) belt body velocity at the end of the step, which started at ``speed`` along the
    belt; ``direction``: (n_belts, 2) the belts' (cos, sin) of their incline (None: all flat).  The fish's mean
    force on the belt over the step is m * dv / dt.
    """
    c, s = (np.ones(len(vel_end)), np.zeros(len(vel_end))) if direction is None else (direction[:, 0], direction[:, 1])
    along = mass_kg * (vel_end[:, 0] * c + vel_end[:, 2] * s - speed_set_mps) / dt_s
    normal = mass_kg * (vel_end[:, 2] * c - vel_end[:, 0] * s) / dt_s
    load = -along
    mass = -normal / gravity_mps2 if gravity_mps2 > 0 else np.zeros_like(normal)
    return load, mass


def spine_point_local(geometry: FishGeometry, s: float) -> tuple[int, np.ndarray]:
    """(body index, position in that body's frame) of the spine point at fraction s from the snout."""
    d = s * geometry.length_m
    for i, b in enumerate(geometry.bodies):
        if b.s_start <= s <= b.s_end or i == len(geometry.bodies) - 1:
            return i, np.array([b.com_from_snout_m - d, 0.0, 0.0])
    raise AssertionError("unreachable")
