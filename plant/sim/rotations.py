"""Rotation vectors and matrices for many bodies at once (numpy, no Python loop per body).

Exudyn's ``NodeRigidBodyRotVecLG`` stores a body's orientation as a rotation vector and its
angular velocity in body coordinates; the plant reads all of them in one vector per step and
needs their matrices to place sensors and measure joint angles.

>>> import numpy as np
>>> r = np.array([[0.0, 0.0, np.pi / 2]])
>>> np.round(rotvec_to_matrix(r)[0] @ [1.0, 0.0, 0.0], 6).tolist()
[0.0, 1.0, 0.0]
>>> np.allclose(matrix_to_rotvec(rotvec_to_matrix(r)), r)
True
"""

from __future__ import annotations

import numpy as np


def rotvec_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for an (n, 3) array of rotation vectors -> (n, 3, 3)."""
    rv = np.asarray(rv, dtype=float)
    th2 = np.einsum("...i,...i->...", rv, rv)
    th = np.sqrt(th2)
    small = th < 1e-6
    if small.any():  # the series near zero (rare after the first step: this runs for every body every step)
        safe = np.where(small, 1.0, th)
        a = np.where(small, 1.0 - th2 / 6.0, np.sin(safe) / safe)
        b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / (th * th)
    x, y, z = rv[..., 0], rv[..., 1], rv[..., 2]
    xx, yy, zz = x * x, y * y, z * z
    ax, ay, az = a * x, a * y, a * z
    bx = b * x
    bxy, bxz, byz = bx * y, bx * z, b * y * z
    out = np.empty(rv.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1.0 - b * (yy + zz)
    out[..., 1, 1] = 1.0 - b * (xx + zz)
    out[..., 2, 2] = 1.0 - b * (xx + yy)
    out[..., 0, 1] = bxy - az
    out[..., 1, 0] = bxy + az
    out[..., 0, 2] = bxz + ay
    out[..., 2, 0] = bxz - ay
    out[..., 1, 2] = byz - ax
    out[..., 2, 1] = byz + ax
    return out


_SKEW_UPPER, _SKEW_LOWER = np.array([7, 2, 3]), np.array([5, 6, 1])
"""Entries (2, 1), (0, 2), (1, 0) and (1, 2), (2, 0), (0, 1) of a flattened 3 x 3 matrix: its antisymmetric part."""


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """Logarithm of (n, 3, 3) rotation matrices -> (n, 3) rotation vectors (angle in [0, pi])."""
    rot = np.asarray(rot, dtype=float)
    flat = rot.reshape(rot.shape[:-2] + (9,))  # two takes instead of six views and a stack: this runs every step
    cos = ((flat[..., 0] + flat[..., 4] + flat[..., 8] - 1.0) / 2.0).clip(-1.0, 1.0)
    th = np.arccos(cos)
    w = flat[..., _SKEW_UPPER] - flat[..., _SKEW_LOWER]
    sin = np.sin(th)
    small = sin < 1e-6
    if small.any():
        scale = np.where(small, 0.5 + th**2 / 12.0, th / (2.0 * np.where(small, 1.0, sin)))
    else:
        scale = th / (2.0 * sin)
    out = w * scale[..., None]
    # near pi the antisymmetric part vanishes: take the axis from the symmetric part
    near_pi = (th > np.pi - 1e-3)
    if near_pi.any():
        for i in np.flatnonzero(near_pi):
            m = (rot[i] + np.eye(3)) / 2.0
            axis = m[np.argmax(np.diag(m))]
            out[i] = axis / np.linalg.norm(axis) * th[i]
    return out


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def lying_orientation(yaw_rad: float, side: int) -> np.ndarray:
    """Body orientation of a fish lying on its flank with its head towards ``yaw_rad``.

    Body frame: x to the head, y to the back, z to the left flank.  ``side = +1``: the right
    flank is down (body z up); ``side = -1``: the left flank is down (body z down).
    """
    return rot_z(yaw_rad) @ (np.eye(3) if side >= 0 else rot_x(np.pi))


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices -> (n, 4) unit quaternions (w, x, y, z), w >= 0."""
    rv = matrix_to_rotvec(rot)
    th = np.linalg.norm(rv, axis=-1, keepdims=True)
    axis = np.where(th > 1e-12, rv / np.where(th > 1e-12, th, 1.0), 0.0)
    return np.concatenate([np.cos(th / 2), axis * np.sin(th / 2)], axis=-1)
