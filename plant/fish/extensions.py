"""Extensions of the fish model for effects the paper left out (its discussion lists them).

Each is a ``[plant.extensions.<name>]`` table of a scenario; the defaults switch it off.  They
are the candidate causes that ``fishfmu diagnose`` fits to measured data (with ``drive_droop``,
which lives in the conveyor-drive FMU as its ``belt_slip`` parameter).

- ``direction_friction``: salmon scales lie towards the tail, so skin slides more easily head
  first than tail first, and differently again sideways.  The fish-belt friction coefficient is
  multiplied by ``head``, ``tail`` or ``across`` according to the direction in which the fish
  slips over the belt, blended smoothly between them (``cos^2``/``sin^2`` of the angle between
  the slip and the fish's heading).
- ``rigor_mortis``: joints stiffen and their range shrinks as rigor sets in and resolves, a bump
  in hours post mortem: ``R(h) = exp(-((h - peak_h) / width_h)^2)``; stiffness x ``1 + stiffness_gain
  R``, limits x ``1 - limit_loss R``.
- ``mucus_friction``: the mucus layer dries and thins after death, so friction on belts and guides
  changes with hours post mortem: x ``1 + gain (1 - exp(-h / time_constant_h))``.
- ``adhesion``: slime makes touching fish stick: an attracting force ``force_n`` per pair of touching
  contact spheres of different fish (within ``range_m`` of touching).
- ``guide_wear``: guide liners grip harder where they are worn rough (or caked with dried slime and scales): the
  side guides are built of sections ``section_m`` long, each with its own fish-guide friction, rising linearly
  with x from the friction at the infeed end of the line to ``1 + rise`` times it at the outfeed end.

>>> ext = Extensions()
>>> ext.active()
[]
>>> ext.rigor_mortis.stiffness_gain = 3.0
>>> ext.active(), round(ext.rigor_mortis.joint_factors(24.0)[0], 3)
(['rigor_mortis'], 4.0)
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from plant.validation import Strict

FRICTION_LEVELS = np.round(np.arange(0.2, 3.0001, 0.01), 2)
"""Multipliers of the fish-belt friction a fish can take: one GeneralContact friction material each."""


class DirectionFriction(Strict):
    """Friction multipliers by the direction in which the fish slips over the belt."""

    head: float = Field(1.0, gt=0.2, le=3.0, description="slipping head first (along the scales)")
    tail: float = Field(1.0, gt=0.2, le=3.0, description="slipping tail first (against the scales)")
    across: float = Field(1.0, gt=0.2, le=3.0, description="slipping sideways")

    @property
    def on(self) -> bool:
        return (self.head, self.tail, self.across) != (1.0, 1.0, 1.0)

    def factor(self, along: np.ndarray, across: np.ndarray) -> np.ndarray:
        """Multiplier for slip components along the heading (+: head first) and across it."""
        norm2 = along**2 + across**2
        c2 = np.where(norm2 > 0, along**2 / np.where(norm2 > 0, norm2, 1.0), 1.0)
        longitudinal = np.where(along >= 0, self.head, self.tail)
        return longitudinal * c2 + self.across * (1.0 - c2)


def stiffening_limit_loss(stiffening: float) -> float:
    """The fraction of joint range lost with joints (1 + ``stiffening``) x stiffer: one law for a fish's
    stiffness and range (0 at 0, 0.3 at 3, towards 0.6), used where both must follow one number."""
    return 0.6 * stiffening / (stiffening + 3.0)


class RigorMortis(Strict):
    """Joint stiffness and range against hours post mortem."""

    stiffness_gain: float = Field(0.0, ge=0.0, le=50.0, description="extra stiffness at full rigor, x soft stiffness")
    limit_loss: float = Field(0.0, ge=0.0, le=0.9, description="fraction of the joint range lost at full rigor")
    peak_h: float = Field(24.0, gt=0.0, le=200.0, description=(
        "hours post mortem of full rigor (farmed salmon at ice temperature: onset after some hours, "
        "strongest about a day after death; assumption from the processing literature)"))
    width_h: float = Field(20.0, gt=1.0, le=200.0, description="how long rigor lasts around its peak (assumption)")

    @property
    def on(self) -> bool:
        return self.stiffness_gain > 0.0 or self.limit_loss > 0.0

    def index(self, hours: float) -> float:
        return math.exp(-(((hours - self.peak_h) / self.width_h) ** 2))

    def joint_factors(self, hours: float) -> tuple[float, float]:
        """(stiffness factor, limit factor) for a fish this many hours after death."""
        r = self.index(hours)
        return 1.0 + self.stiffness_gain * r, 1.0 - self.limit_loss * r


class MucusFriction(Strict):
    """Friction on belts and guides against hours post mortem."""

    gain: float = Field(0.0, ge=-0.8, le=10.0, description="relative change of friction once the mucus has dried")
    time_constant_h: float = Field(24.0, gt=0.5, le=500.0, description="how fast it dries (assumption)")

    @property
    def on(self) -> bool:
        return self.gain != 0.0

    def factor(self, hours: float) -> float:
        return 1.0 + self.gain * (1.0 - math.exp(-hours / self.time_constant_h))


class Adhesion(Strict):
    """Touching fish attract each other (slime)."""

    force_n: float = Field(0.0, ge=0.0, le=50.0, description="attraction per pair of touching contact spheres")
    range_m: float = Field(0.005, ge=0.0, le=0.05, description="how far apart two sphere surfaces still stick")

    @property
    def on(self) -> bool:
        return self.force_n > 0.0


class GuideWear(Strict):
    """Fish-guide friction rising along the line, in sections of the side guides."""

    rise: float = Field(0.0, ge=-0.8, le=10.0, description=(
        "fish-guide friction at the outfeed end of the line is (1 + rise) times that at the infeed end, linearly in "
        "x between them (0: off)"))
    section_m: float = Field(0.2, ge=0.05, le=2.0, description=(
        "length of a guide section with its own friction (each takes the friction at its middle)"))

    @property
    def on(self) -> bool:
        return self.rise != 0.0

    def sections(self, x_start_m: float, x_end_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(boundaries, friction factors): the sections' x boundaries from ``x_start_m`` to ``x_end_m`` (the last
        one shorter where the line is not a whole number of sections) and each section's factor on the
        fish-guide friction, ``1 + rise (x_mid - x_start) / (x_end - x_start)``."""
        n = max(1, math.ceil((x_end_m - x_start_m) / self.section_m - 1e-9))
        edges = np.minimum(x_start_m + self.section_m * np.arange(n + 1), x_end_m)
        mid = 0.5 * (edges[:-1] + edges[1:])
        return edges, 1.0 + self.rise * (mid - x_start_m) / (x_end_m - x_start_m)


class Extensions(Strict):
    """The ``[plant.extensions]`` table: every candidate effect, off by default."""

    direction_friction: DirectionFriction = Field(default_factory=DirectionFriction)
    rigor_mortis: RigorMortis = Field(default_factory=RigorMortis)
    mucus_friction: MucusFriction = Field(default_factory=MucusFriction)
    adhesion: Adhesion = Field(default_factory=Adhesion)
    guide_wear: GuideWear = Field(default_factory=GuideWear)

    def active(self) -> list[str]:
        return [name for name in type(self).model_fields if getattr(self, name).on]


def friction_level(multiplier: float | np.ndarray) -> np.ndarray:
    """Index of the nearest friction level for a multiplier (clipped to the available range)."""
    m = np.clip(np.asarray(multiplier, dtype=float), FRICTION_LEVELS[0], FRICTION_LEVELS[-1])
    return np.rint((m - FRICTION_LEVELS[0]) / 0.01).astype(np.int64)


def body_friction_levels(level: int, gradient: float, n_bodies: int = 5) -> np.ndarray:
    """Friction level of each body (head first) of a fish at ``level``: with a gradient g along the fish,
    body i takes (1 + g (i - c) / c) times the fish's multiplier, c the middle body (head 1 - g, fin 1 + g)."""
    if gradient == 0.0:
        return np.full(n_bodies, int(level), dtype=np.int64)
    c = 0.5 * (n_bodies - 1)
    factor = 1.0 + gradient * (np.arange(n_bodies) - c) / c
    return friction_level(FRICTION_LEVELS[int(level)] * factor)


def highest_body_level(levels: np.ndarray, gradient: float, n_bodies: int) -> int:
    """The highest friction level any body of fish at ``levels`` takes (:func:`body_friction_levels`): without
    directional friction no fish leaves its level, and the friction table needs none above it."""
    return max((int(body_friction_levels(int(lv), gradient, n_bodies).max()) for lv in levels), default=0)


# ---------------------------------------------------------------- the forces, as functions of the state

def direction_friction_levels(spine_xy: np.ndarray, mid_velocity_xy: np.ndarray, belt_speed_mps: np.ndarray,
                              mucus: np.ndarray, level_now: np.ndarray, direction: DirectionFriction,
                              moving_above_mps: float) -> np.ndarray:
    """Each fish's friction level from the way it slips over its belt now: ``spine_xy`` (fish, 3, 2)
    holds its mid, head-side and tail-side spine points, ``mid_velocity_xy`` the velocity of its mid
    body, ``belt_speed_mps`` that of the belt under it.  A fish that does not slip (slower than
    ``moving_above_mps``) keeps ``level_now``: static friction has no direction."""
    heading = spine_xy[:, 1] - spine_xy[:, 2]
    heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-9)
    slip = mid_velocity_xy - np.stack([belt_speed_mps, np.zeros(len(belt_speed_mps))], axis=1)
    along = np.einsum("ij,ij->i", slip, heading)
    across = heading[:, 0] * slip[:, 1] - heading[:, 1] * slip[:, 0]
    moving = np.hypot(along, across) > moving_above_mps
    return np.where(moving, friction_level(mucus * direction.factor(along, across)), level_now)


def adhesion_forces(centres: np.ndarray, radii: np.ndarray, body_of_sphere: np.ndarray, fish_of_body: np.ndarray,
                    n_bodies: int, adhesion: Adhesion) -> np.ndarray:
    """The attraction on each body (n_bodies, 3) [N]: ``adhesion.force_n`` per pair of spheres of
    different fish whose surfaces are within ``adhesion.range_m``, along the line between their
    centres, equal and opposite on the two bodies."""
    from scipy.spatial import cKDTree  # slow to import (0.3 s), and needed only with the adhesion extension on
    force = np.zeros((n_bodies, 3))
    if len(centres) < 2:
        return force
    pairs = cKDTree(centres).query_pairs(2.0 * float(radii.max()) + adhesion.range_m, output_type="ndarray")
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        bi, bj = body_of_sphere[i], body_of_sphere[j]
        d = centres[j] - centres[i]
        dist = np.linalg.norm(d, axis=1)
        touching = (fish_of_body[bi] != fish_of_body[bj]) & (dist < radii[i] + radii[j] + adhesion.range_m)
        unit = d[touching] / np.maximum(dist[touching], 1e-9)[:, None]
        np.add.at(force, bi[touching], adhesion.force_n * unit)
        np.add.at(force, bj[touching], -adhesion.force_n * unit)
    return force
