"""The four joints of a fish: limits from Table III, a soft spring inside them, a stiff one beyond.

Per joint and axis (x twist, y bending to the sides, z bending towards back/belly) the torque
against the relative rotation angle ``theta`` is

    tau(theta) = k_soft * theta + (k_limit - k_soft) * phi(|theta|) * sign(theta)

where ``phi`` is zero inside ``limit - w``, quadratic across ``[limit - w, limit + w]`` and
linear beyond, so the stiffness rises smoothly (C1) from ``k_soft`` to ``k_limit`` around the
limit.  ``k_soft`` follows the sag rule of :class:`plant.sim.params.JointParams`; ``k_limit`` is
the bodies' reduced inertia times the limit frequency of the numerics.

Exudyn's rigid-body spring-damper is linear, and a Python callback per joint per step would
cost more than the whole fish.  So the plant re-linearises each joint once per communication
step around the angle it will reach by the end of the step (:func:`linearize`), and writes new
stiffness/offset values only to joints whose linearisation changed.

>>> law = JointLaws(limit_rad=np.array([[0.2, 0.2, 0.2]]), k_soft=np.array([[1.0, 1.0, 1.0]]),
...                 k_limit=np.array([[20.0, 20.0, 20.0]]), transition=0.15, damping=np.ones((1, 3)))
>>> float(torque(law, np.array([[0.1, 0.0, 0.0]]))[0, 0])  # inside the limit: soft spring
0.1
>>> round(float(tangent(law, np.array([[0.5, 0.0, 0.0]]))[0, 0]), 6)  # well beyond: stiff
20.0
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from plant.fish import fish_data
from plant.fish.fish_body import FishGeometry
from plant.sim.params import JointParams, NumericsParams
from plant.sim.rotations import matrix_to_rotvec

AXES = ("twist", "lateral", "dorsoventral")


@dataclass(frozen=True)
class JointLaws:
    """Spring laws of J joints, arrays of shape (J, 3) over the axes (x, y, z)."""

    limit_rad: np.ndarray
    k_soft: np.ndarray
    """Stiffness inside the limits [N m/rad]."""
    k_limit: np.ndarray
    """Stiffness beyond the limits [N m/rad]."""
    transition: float
    """Half-width of the stiffening zone as a fraction of the limit."""
    damping: np.ndarray
    """Rotational damping [N m s/rad]."""

    @cached_property
    def zone(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(start, end, 4 w, 2 w) of the stiffening zone, w its half-width: worked out once, read every step."""
        w = self.transition * self.limit_rad
        return self.limit_rad - w, self.limit_rad + w, 4.0 * w, 2.0 * w

    @cached_property
    def table(self) -> np.ndarray:
        """(8, J, 3): the limit, k_soft, k_limit, the zone's (start, end, 4 w, 2 w) and where the soft spring ends
        (as :func:`relinearized` works it out), for the plant's C kernel (plant.sim.kernels)."""
        return np.ascontiguousarray(np.stack((self.limit_rad, self.k_soft, self.k_limit, *self.zone,
                                              self.limit_rad * (1.0 - self.transition))), dtype=float)


def stack_laws(laws: list[JointLaws]) -> JointLaws:
    """One set of arrays for the joints of many fish (same transition width assumed)."""
    if not laws:
        z = np.zeros((0, 3))
        return JointLaws(z, z, z, 0.15, z)
    return JointLaws(np.vstack([x.limit_rad for x in laws]), np.vstack([x.k_soft for x in laws]),
                     np.vstack([x.k_limit for x in laws]), laws[0].transition, np.vstack([x.damping for x in laws]))


def _phi(law: JointLaws, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi(|theta|) and its slope, for |theta| = a (its last two axes (J, 3) those of the law)."""
    lo, hi, w4, w2 = law.zone
    dz = a - lo
    beyond, past_lo = a >= hi, a > lo  # past_lo and not beyond: the zone; neither: inside
    phi = np.where(beyond, a - law.limit_rad, np.where(past_lo, dz * dz / w4, 0.0))
    slope = np.where(beyond, 1.0, np.where(past_lo, dz / w2, 0.0))
    return phi, slope


def torque(law: JointLaws, theta: np.ndarray) -> np.ndarray:
    """Spring torque for relative rotation angles ``theta`` (J, 3)."""
    phi, _ = _phi(law, np.abs(theta))
    return law.k_soft * theta + (law.k_limit - law.k_soft) * phi * np.sign(theta)


def tangent(law: JointLaws, theta: np.ndarray) -> np.ndarray:
    """d torque / d theta."""
    _, slope = _phi(law, np.abs(theta))
    return law.k_soft + (law.k_limit - law.k_soft) * slope


def linearize(law: JointLaws, theta_now: np.ndarray, theta_next: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(stiffness, offset) of a linear spring ``k (theta - offset)`` for the coming step.

    The stiffness is the larger tangent of now and of the predicted end of the step (so a joint
    running into its limit is already stiff when it gets there); the offset makes the linear
    spring give the exact torque now.
    """
    gap = law.k_limit - law.k_soft
    phi, slope = _phi(law, np.abs(np.stack((theta_now, theta_next))))  # now and next at once
    tangents = law.k_soft + gap * slope
    k = np.maximum(tangents[0], tangents[1])  # tangent(now), tangent(next)
    offset = theta_now - (law.k_soft * theta_now + gap * phi[0] * np.sign(theta_now)) / k  # torque(now) / k
    return k, offset


def relinearized(laws: JointLaws, rot_a: np.ndarray, rot_b: np.ndarray, omega_a: np.ndarray, omega_b: np.ndarray,
                 active: np.ndarray, dt_s: float, k_now: np.ndarray, offset_now: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joints' linear springs for the coming step of ``dt_s``: (changed (J,) bool, stiffness (J, 3),
    offset (J, 3)); only the ``changed`` joints need new values in Exudyn.

    Joint j joins bodies a and b (rotations ``rot_a``/``rot_b`` (J, 3, 3), body-frame angular velocities
    ``omega_a``/``omega_b`` (J, 3)); ``active`` (J,) False for the joints of fish not on the line (parked).
    A joint well inside its limits (most of them) keeps the soft spring: the law is evaluated only for those
    near a limit now or by the end of the step; a spring is changed when its stiffness moves by more than
    2 % or its offset by more than 0.005 rad."""
    rel = np.einsum("nji,njk->nik", rot_a, rot_b)
    theta = matrix_to_rotvec(rel)
    # relative angular velocity in the frame of body a (node velocities are body-frame)
    w_b_in_a = np.einsum("nij,nj->ni", rel, omega_b)
    theta_next = theta + (w_b_in_a - omega_a) * dt_s
    soft_until = laws.limit_rad * (1.0 - laws.transition)
    near = ((np.abs(theta) > soft_until) | (np.abs(theta_next) > soft_until)).any(axis=1)
    near &= active
    if near.any():  # the array's own methods: np.any's dispatch costs more than the test on 4 joints a fish
        # the law over every joint, kept where near (element by element: the same numbers as over those alone);
        # fewer numpy calls than picking the near ones out and putting them back
        k_all, off_all = linearize(laws, theta, theta_next)
        k_new = np.where(near[:, None], k_all, laws.k_soft)
        off_new = np.where(near[:, None], off_all, 0.0)
    else:
        k_new, off_new = laws.k_soft, np.zeros_like(offset_now)
    changed = ((np.abs(k_new - k_now) > 0.02 * k_now).any(axis=1)
               | (np.abs(off_new - offset_now) > 0.005).any(axis=1))
    return changed, k_new, off_new


def joint_laws(geometry: FishGeometry, joints: JointParams, numerics: NumericsParams, gravity_mps2: float,
               inertias: list[np.ndarray] | None = None, stiffness_factor: float = 1.0,
               limit_factor: float = 1.0) -> JointLaws:
    """Spring laws of one fish's four joints.

    ``inertias``: the principal inertias the bodies are simulated with (after shaping);
    ``stiffness_factor`` / ``limit_factor``: per-fish multipliers (e.g. rigor mortis).
    """
    t3 = fish_data.table3()
    bodies = geometry.bodies
    inertias = inertias or [np.array(b.inertia_kgm2) for b in bodies]
    limits, k_soft, k_limit, damping = [], [], [], []
    for j in range(len(bodies) - 1):
        xj = geometry.joint_from_snout_m[j]
        row = t3.iloc[j]
        lat = np.radians(row["swing1_deg"]) * joints.limit_scale * limit_factor
        dv = np.radians(row["swing2_deg"]) * joints.limit_scale * limit_factor
        twist_deg = max(abs(row["twist_low_deg"]), abs(row["twist_high_deg"]))
        locked = twist_deg == 0.0
        twist = np.radians(joints.locked_twist_deg if locked else twist_deg * joints.limit_scale * limit_factor)
        lim = np.array([twist, lat, dv])

        # reduced inertia of the two bodies about their own centres of mass: the translational coupling
        # is compliant, so a joint spring turns each body about its centre of mass, not about the joint
        ia, ib = inertias[j], inertias[j + 1]
        i_red = ia * ib / (ia + ib)
        k_lim = i_red * numerics.joint_limit_omega_rad_s**2

        # sag rule: the lighter side of the joint, held horizontally, bends sag_fraction of the limit
        head_side, tail_side = bodies[: j + 1], bodies[j + 1:]
        side = min((head_side, tail_side), key=lambda bs: sum(b.mass_kg for b in bs))
        m_side = sum(b.mass_kg for b in side)
        lever = abs(sum(b.mass_kg * b.com_from_snout_m for b in side) / m_side - xj)
        tau_g = m_side * gravity_mps2 * lever
        # a limp fish is at most a third as stiff inside its limits as beyond them; rigor (stiffness_factor)
        # stiffens it from there, up to the limit stiffness (a fish in full rigor is nearly rigid)
        soft = np.minimum(tau_g / (joints.sag_fraction * lim) * joints.stiffness_scale, k_lim / 3.0)
        soft = np.minimum(soft * stiffness_factor, k_lim)
        if locked:
            soft[0] = k_lim[0]
        limits.append(lim)
        k_soft.append(soft)
        k_limit.append(k_lim)
        damping.append(2.0 * joints.damping_ratio * np.sqrt(k_lim * i_red))
    return JointLaws(np.array(limits), np.array(k_soft), np.array(k_limit), joints.limit_transition, np.array(damping))
