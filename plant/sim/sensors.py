"""What the plant measures, computed from the body states of one communication step.

- photo-eyes: a beam across the line (along y) at (x, z) is blocked when it passes through a
  fish's body, taken from its outline (a stadium-shaped cross-section every centimetre), not from
  the coarser contact spheres, whose valleys would let a beam through a fish; an eye with a latency
  reports that state that much later (:class:`BeamDelay`);
- belt load: the force the fish put on a belt along x and down, from the belt body's momentum
  change over the step (nothing else acts on it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from plant.contract.line import Line
from plant.sim import kernels
from plant.sim.equipment import Seen, Step

if TYPE_CHECKING:  # the system's outline cross-sections are read, the system is not built here
    from plant.sim.model import PlantModel


def sphere_centres(body_pos: np.ndarray, body_rot: np.ndarray, sphere_body: np.ndarray,
                   sphere_local: np.ndarray) -> np.ndarray:
    """World positions (n_spheres, 3) of all contact spheres."""
    return body_pos[sphere_body] + np.einsum("nij,nj->ni", body_rot[sphere_body], sphere_local)


def capsules_cut(centre: np.ndarray, axis: np.ndarray, half_len: np.ndarray, radius: np.ndarray,
                 beam_xz: np.ndarray, span_y_m: np.ndarray) -> np.ndarray:
    """True where a beam at (x, z) ``beam_xz`` (..., 2), spanning y from ``span_y_m[..., 1]`` to ``span_y_m[..., 0]``,
    cuts a fish cross-section; element by element, the arrays broadcast against each other (over their leading axes).

    A cross-section is a capsule: the segment ``centre +- s * axis`` (|s| <= half_len, axis = the body's dorsal
    direction; (..., 3) each) thickened by ``radius``.  The beam runs along y, so only the distance in the x-z plane
    counts: minimise it over s (a quadratic) and compare with the radius."""
    dx = centre[..., 0] - beam_xz[..., 0]
    dz = centre[..., 2] - beam_xz[..., 1]
    uu = axis[..., 0] ** 2 + axis[..., 2] ** 2
    s = -(dx * axis[..., 0] + dz * axis[..., 2]) / np.where(uu > 1e-12, uu, 1.0)
    s = np.clip(s, -half_len, half_len)
    ex = dx + s * axis[..., 0]
    ez = dz + s * axis[..., 2]
    y = centre[..., 1] + s * axis[..., 1]
    return (ex * ex + ez * ez < radius ** 2) & (y < span_y_m[..., 0] + radius) & (y > span_y_m[..., 1] - radius)


def photoeyes_blocked(section_centres: np.ndarray, section_axes: np.ndarray, half_len: np.ndarray,
                      radius: np.ndarray, beams_xz: np.ndarray, span_y_m: np.ndarray,
                      pairs: np.ndarray | None = None) -> np.ndarray:
    """(n_beams,) True where a beam at (x, z), spanning y from ``span_y_m[:, 1]`` to ``span_y_m[:, 0]`` (between
    the guides there: (left, right) per beam), cuts a fish cross-section (:func:`capsules_cut`), every beam against
    every cross-section.  ``pairs`` (n_beams, n_sections), when given: only these (beam, cross-section) pairs are
    looked at.
    """
    if len(beams_xz) == 0 or len(section_centres) == 0:
        return np.zeros(len(beams_xz), dtype=bool)
    span = np.asarray(span_y_m, dtype=float).reshape(-1, 2)
    hit = capsules_cut(section_centres[None], section_axes[None], half_len[None], radius[None], beams_xz[:, None],
                       span[:, None])
    if pairs is not None:
        hit &= pairs
    return hit.any(axis=1)


def outline_reach_m(model: PlantModel) -> np.ndarray:
    """(n_bodies,) the farthest any point of each body's outline lies from the body's centre along any direction
    (a cross-section's offset along the body, half its length and its radius): a body whose centre is farther than
    this from a beam along x cannot cut it."""
    n_bodies = int(model.section_body.max()) + 1 if len(model.section_body) else 0
    reach = np.zeros(n_bodies)
    np.maximum.at(reach, model.section_body, np.abs(model.section_x) + model.section_half_len + model.section_radius)
    return reach


def beams_blocked(model: PlantModel, pos: np.ndarray, rot: np.ndarray, body_on: np.ndarray, beams_xz: np.ndarray,
                  span_y_m: np.ndarray, reach_m: np.ndarray | None = None) -> np.ndarray:
    """(n_beams,) True where a beam cuts the outline of a body of a fish on the line (``body_on``), from the
    bodies' positions and rotations.  Each beam is tested only against the cross-sections near it: those of the
    bodies whose centre lies within their ``reach_m`` (:func:`outline_reach_m`, worked out when not given) of it
    along x, and of them those whose centre lies within their half-length and radius of it along x (no other can
    reach it)."""
    blocked = np.zeros(len(beams_xz), dtype=bool)
    if len(beams_xz) == 0 or len(model.section_body) == 0:
        return blocked
    reach = (outline_reach_m(model) if reach_m is None else reach_m) + 1e-9  # 1e-9: rounding of the centres
    reach = np.pad(reach, (0, len(pos) - len(reach))) if len(reach) < len(pos) else reach  # no outline: no reach
    near = body_on[:, None] & (np.abs(pos[:, :1] - beams_xz[None, :, 0]) < reach[:, None])  # (bodies, beams)
    sel = np.flatnonzero(near.any(axis=1)[model.section_body])
    if not len(sel):
        return blocked
    b = model.section_body[sel]
    r = rot[b]
    centres = pos[b] + r[:, :, 0] * model.section_x[sel][:, None]
    half_len, radius = model.section_half_len[sel], model.section_radius[sel]
    beam, section = np.nonzero(near[b].T & (np.abs(centres[:, 0] - beams_xz[:, :1]) < half_len + radius + 1e-9))
    if len(beam):
        span = np.asarray(span_y_m, dtype=float).reshape(-1, 2)
        cut = capsules_cut(centres[section], r[section, :, 1], half_len[section], radius[section], beams_xz[beam],
                           span[beam])
        blocked[beam[cut]] = True
    return blocked


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
        self._model, self._reach_m = None, np.zeros(0)  # the system the reaches were worked out for

    @classmethod
    def of(cls, line: Line, comm_step_s: float) -> PhotoEyes:
        beams = np.array([[p.x_m, p.z_m] for p in line.photoeyes]).reshape(-1, 2)
        return cls(tuple(p.id for p in line.photoeyes), beams, np.column_stack(line.guide_y_at(beams[:, 0])),
                   BeamDelay([p.latency_s for p in line.photoeyes], comm_step_s))

    def before_solve(self, step: Step, q: np.ndarray, v: np.ndarray) -> None:
        pass  # a beam acts on nothing

    def after_solve(self, step: Step, seen: Seen) -> dict[str, dict]:
        m = step.model
        if m is not self._model:  # once per system: it changes only when the plant rebuilds it
            reach = outline_reach_m(m) + 1e-9  # as beams_blocked pads it: a body without an outline reaches nowhere
            self._model, self._reach_m = m, np.pad(reach, (0, max(0, len(seen.pos) - len(reach))))
        blocked = kernels.beams_blocked(seen.pos, seen.rot, seen.body_on, self._reach_m,
                                        (m.section_body, m.section_x, m.section_half_len, m.section_radius),
                                        self.beams_xz, self.span_y_m)
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

