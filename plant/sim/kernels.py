"""The plant's per-step arithmetic in C: every body's rotation matrix, the joints' springs, the photo-eye beams and
the health check's first look.

Each of these is a few dozen numpy calls on arrays of a few dozen rows, run every communication step, where a
call's fixed cost is the cost (docs/performance.md): together they were about half of the plant's own Python per
step.  In C (``plant/sim/kernels_c.c``, compiled by pip at install: after editing it, install again) each is one
pass over its rows.

Each kernel repeats the floating-point operations of its numpy reference, element by element and in the same
order, and gives the same numbers to the bit (``tests/test_kernels.py`` holds each to its reference on random
and edge-case inputs): the references stay where they were (:func:`plant.sim.rotations.rotvec_to_matrix`,
:func:`plant.sim.joints.relinearized`, :func:`plant.sim.sensors.beams_blocked`, ``plant.sim.health._all_clear``) and
say what is computed; a run's results are the same with either.  Two things are left to numpy to keep that so:
the arccos of a joint's angle (numpy's own vectorised arccos differs from the C library's in the last bit) and the
rare joint bent near half a turn (its rotation vector comes from the matrix's symmetric part).
"""

from __future__ import annotations

import numpy as np

from plant.sim import kernels_c
from plant.sim.joints import JointLaws
from plant.sim.joints import relinearized as relinearized_reference


def rotation_matrices(coords: np.ndarray, column: int = 3) -> np.ndarray:
    """(n, 3, 3) the rotation matrices of the rotation vectors ``coords[:, column:column + 3]`` (``coords`` (n, m),
    C-contiguous float64: a body's coordinates as Exudyn holds them, position then rotation vector)."""
    out = np.empty((len(coords), 3, 3))
    kernels_c.rotation_matrices(coords, column, out)
    return out


def relinearized(laws: JointLaws, rot: np.ndarray, velocities: np.ndarray, joint_bodies: np.ndarray,
                 active: np.ndarray, dt_s: float, k_now: np.ndarray, offset_now: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`plant.sim.joints.relinearized` from every body's rotation ``rot`` (nb, 3, 3) and velocities (nb, 6:
    velocity, then body-frame angular velocity) and each joint's two bodies ``joint_bodies`` (J, 2)."""
    n = len(joint_bodies)
    rel, cos = np.empty((n, 3, 3)), np.empty(n)
    kernels_c.joint_cosines(rot, joint_bodies, rel, cos)
    changed, k_new, offset_new = np.empty(n, dtype=bool), np.empty((n, 3)), np.empty((n, 3))
    if kernels_c.joint_springs(rel, np.arccos(cos), velocities, 3, joint_bodies, active, dt_s, laws.table, k_now,
                              offset_now, changed, k_new, offset_new):
        return changed, k_new, offset_new
    a, b = joint_bodies[:, 0], joint_bodies[:, 1]  # a joint near half a turn: the reference takes it
    return relinearized_reference(laws, rot[a], rot[b], velocities[a, 3:], velocities[b, 3:], active, dt_s, k_now,
                                  offset_now)


def beams_blocked(pos: np.ndarray, rot: np.ndarray, body_on: np.ndarray, reach_m: np.ndarray,
                  sections: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], beams_xz: np.ndarray,
                  span_y_m: np.ndarray) -> np.ndarray:
    """:func:`plant.sim.sensors.beams_blocked`, given each body's reach (nb,) with the reference's 1e-9 added
    (:func:`plant.sim.sensors.outline_reach_m`) and the system's cross-sections (body, offset along it, half length,
    radius)."""
    blocked = np.empty(len(beams_xz), dtype=bool)
    kernels_c.beams_blocked(pos, rot, body_on, reach_m, *sections, beams_xz, span_y_m, blocked)
    return blocked


def all_clear(pos: np.ndarray, velocities: np.ndarray, body_on: np.ndarray, bounds: tuple[float, ...]) -> bool:
    """:func:`plant.sim.health._all_clear` over the bodies on the line (``body_on``), given its ``bounds``
    (``_LineBounds.clear_bounds``) and the bodies' (n, 6) velocities (the velocity, then the angular velocity)."""
    return kernels_c.all_clear(pos, velocities, 0, body_on, *bounds)
