"""Sleeping fish: a fish that rides with its belt, alone, is carried kinematically outside Exudyn.

A fish lying still on a belt moves exactly as the belt does: its bodies translate at the belt's speed
and nothing else acts on it but gravity and the belt's normal force, in equilibrium.  Integrating it
buys nothing, so, as game and robotics engines put resting bodies to sleep, the plant takes such a
fish out of the Exudyn system and moves its bodies with the belt; it puts it back, with that state
(bodies at belt speed, joints as they were), as soon as anything could change its motion.

A fish may sleep (:func:`may_sleep`) when, for ``SLEEP_AFTER_CHECKS`` checks in a row (0.1 s apart),
every body moves with the belt under it (within ``RIDE_TOL_MPS`` and ``SPIN_TOL_RAD_S``) and the fish
lies on one belt, clear of its ends and photo-eyes by ``END_MARGIN_M``, of the guides by
``GUIDE_MARGIN_M`` and of every other fish by ``CLEAR_M``.  A sleeping fish wakes (:func:`must_wake`)
before any of that can change: its belt accelerates by more than a quarter of what friction can
follow (mu g), its leading end comes within ``END_MARGIN_M`` of its belt's end or of a photo-eye, or
another fish comes within ``WAKE_CLEAR_M`` (plus what both can close in one step).  The plant also
wakes a fish where another is about to be dropped.  Off unless ``plant.numerics.sleep`` is set.
"""

from __future__ import annotations

import numpy as np

RIDE_TOL_MPS = 0.005
"""Largest difference between a body's velocity and its belt's that counts as riding with it."""
SPIN_TOL_RAD_S = 0.05
SLEEP_AFTER_CHECKS = 2
"""Consecutive checks (every tenth communication step) a fish must ride before it sleeps."""
END_MARGIN_M = 0.05
"""Distance kept from a belt's downstream end and from a photo-eye's beam (both ways) while asleep."""
GUIDE_MARGIN_M = 0.01
CLEAR_M = 0.10
"""Distance from every other fish at which a riding fish may go to sleep."""
WAKE_CLEAR_M = 0.05
"""A sleeping fish wakes when another fish's box comes this close to its own."""
ACCEL_SHARE = 0.25
"""Share of mu g up to which a belt's acceleration is followed kinematically."""


def fish_boxes(centres: np.ndarray, radii: np.ndarray, fish_of_sphere: np.ndarray, n_fish: int) -> np.ndarray:
    """(n_fish, 2, 3) axis-aligned boxes around each fish's contact spheres (NaN for fish without any)."""
    lo = np.full((n_fish, 3), np.inf)
    hi = np.full((n_fish, 3), -np.inf)
    np.minimum.at(lo, fish_of_sphere, centres - radii[:, None])
    np.maximum.at(hi, fish_of_sphere, centres + radii[:, None])
    box = np.stack([lo, hi], axis=1)
    box[~np.isfinite(box[:, 0, 0])] = np.nan
    return box


def box_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Gaps (len(a), len(b)) between boxes: the largest separation along any axis (<= 0: overlapping)."""
    sep = np.maximum(b[None, :, 0, :] - a[:, None, 1, :], a[:, None, 0, :] - b[None, :, 1, :])
    return np.nan_to_num(sep.max(axis=2), nan=np.inf)


def riding(vel: np.ndarray, omega: np.ndarray, belt_speed_mps: np.ndarray) -> np.ndarray:
    """(n_fish,) True where every body of a fish moves with its belt: ``vel``/``omega`` (n_fish, 5, 3),
    ``belt_speed_mps`` (n_fish, 5) the speed of the belt under each body."""
    rel = vel.copy()
    rel[:, :, 0] -= belt_speed_mps
    return (np.abs(rel).max(axis=(1, 2)) < RIDE_TOL_MPS) & (np.abs(omega).max(axis=(1, 2)) < SPIN_TOL_RAD_S)


def on_one_belt_clear(box: np.ndarray, belt_start_m: np.ndarray, belt_end_m: np.ndarray, beams_x_m: np.ndarray,
                      half_width_m: float) -> np.ndarray:
    """(n,) belt index under each fish box if it lies wholly on one belt, clear of that belt's ends,
    of every photo-eye and of the guides; -1 otherwise."""
    lo, hi = box[:, 0, 0], box[:, 1, 0]
    belt = np.searchsorted(belt_end_m, lo)
    belt = np.clip(belt, 0, len(belt_end_m) - 1)
    ok = (lo >= belt_start_m[belt] + 0.02) & (hi <= belt_end_m[belt] - END_MARGIN_M - 0.2)
    if len(beams_x_m):
        ok &= ~np.any((beams_x_m[None, :] > lo[:, None] - END_MARGIN_M)
                      & (beams_x_m[None, :] < hi[:, None] + END_MARGIN_M + 0.2), axis=1)
    ok &= (box[:, 0, 1] > -half_width_m + GUIDE_MARGIN_M) & (box[:, 1, 1] < half_width_m - GUIDE_MARGIN_M)
    return np.where(ok, belt, -1)


def near_end(box: np.ndarray, belt_end_m: np.ndarray, beams_x_m: np.ndarray, step_m: np.ndarray) -> np.ndarray:
    """(n,) True where a sleeping fish's box (``belt_end_m`` of its own belt, ``step_m`` its travel in one
    step) comes within END_MARGIN_M of its belt's end or of a photo-eye's beam."""
    lo, hi = box[:, 0, 0], box[:, 1, 0] + step_m
    wake = hi > belt_end_m - END_MARGIN_M
    if len(beams_x_m):
        wake |= np.any((beams_x_m[None, :] > lo[:, None] - END_MARGIN_M)
                       & (beams_x_m[None, :] < hi[:, None] + END_MARGIN_M), axis=1)
    return wake


def too_fast_a_change(speed_now_mps: np.ndarray, speed_before_mps: np.ndarray, dt_s: float,
                      mu: np.ndarray, gravity_mps2: float) -> np.ndarray:
    """(n,) True where the belt under a sleeping fish changes speed faster than friction follows at ease."""
    return np.abs(speed_now_mps - speed_before_mps) > ACCEL_SHARE * mu * gravity_mps2 * dt_s
