"""Re-linearising the joints each step (:func:`plant.sim.joints.relinearized`) on hand-made relative rotations:
a joint well inside its limits keeps its soft spring and is not rewritten; one bent past its soft zone, or running
into it within the step, gets the law's tangent and the offset that gives the exact torque now; a parked fish's
joints are left soft."""

from __future__ import annotations

import numpy as np

from plant.sim.joints import JointLaws, linearize, relinearized, torque
from plant.sim.rotations import matrix_to_rotvec, rot_z, rotvec_to_matrix

LIMIT = 0.3  # rad on every axis; soft up to 0.3 * (1 - 0.15) = 0.255 rad
LAWS = JointLaws(limit_rad=np.full((3, 3), LIMIT), k_soft=np.full((3, 3), 2.0), k_limit=np.full((3, 3), 40.0),
                 transition=0.15, damping=np.ones((3, 3)))
SOFT_K, SOFT_OFF = np.full((3, 3), 2.0), np.zeros((3, 3))


def relin(bend_rad, omega_z_rad_s=(0.0, 0.0, 0.0), active=(True, True, True), dt_s=0.01):
    """Three joints: body b turned by ``bend_rad[j]`` about the z axis of body a (a at rest, b turning at
    ``omega_z_rad_s[j]`` about its z), springs at their soft values before."""
    rot_a = np.repeat(np.eye(3)[None], 3, axis=0)
    rot_b = np.array([rot_z(t) for t in bend_rad])
    omega_b = np.array([[0.0, 0.0, w] for w in omega_z_rad_s])
    return relinearized(LAWS, rot_a, rot_b, np.zeros((3, 3)), omega_b, np.array(active), dt_s, SOFT_K, SOFT_OFF)


def test_joints_inside_the_soft_zone_keep_their_springs_and_are_not_rewritten():
    changed, k, off = relin([0.0, 0.1, -0.25])
    assert not changed.any()
    assert np.array_equal(k, SOFT_K) and np.array_equal(off, SOFT_OFF)


def test_a_joint_past_its_soft_zone_gets_the_tangent_and_the_exact_torque_now():
    changed, k, off = relin([0.1, 0.4, 0.0])  # joint 1 bent 0.4 rad: past limit + zone (0.345), on the stiff line
    assert changed.tolist() == [False, True, False]
    assert np.allclose(k[1], [2.0, 2.0, 40.0])  # only its z axis is bent
    tau = torque(LAWS, np.array([[0.0, 0.0, 0.4]]))[0, 2]
    assert np.isclose(tau, 2.0 * 0.4 + 38.0 * (0.4 - LIMIT))  # 4.6 N m: soft spring plus the stiff one beyond
    assert np.isclose(k[1, 2] * (0.4 - off[1, 2]), tau)  # the linear spring gives that torque now
    assert np.array_equal(k[[0, 2]], SOFT_K[[0, 2]])


def test_a_joint_running_into_its_limit_within_the_step_is_stiff_before_it_gets_there():
    # at 0.25 rad (soft) turning at 2 rad/s: at 0.27 rad by the end of 10 ms, inside the zone [0.255, 0.345]
    changed, k, _ = relin([0.25, 0.0, 0.0], omega_z_rad_s=(2.0, 0.0, 0.0))
    assert changed.tolist() == [True, False, False]
    slope_end = (0.27 - 0.255) / (2.0 * 0.045)  # the zone's quadratic: phi' = (a - lo) / (2 w)
    assert np.isclose(k[0, 2], 2.0 + 38.0 * slope_end)


def test_the_joints_of_a_parked_fish_stay_soft_however_bent():
    changed, k, off = relin([0.4, 0.4, 0.4], active=(False, True, False))
    assert changed.tolist() == [False, True, False]
    assert np.array_equal(k[[0, 2]], SOFT_K[[0, 2]]) and np.array_equal(off[[0, 2]], SOFT_OFF[[0, 2]])


def test_the_bound_that_skips_soft_joints_never_skips_one_the_law_would_stiffen():
    # 2000 joints bent about random axes by 0 to 0.4 rad (the soft zone ends at 0.255 rad), turning at up to
    # 6 rad/s, some of them stiff before: every joint's spring is what the law gives it, worked out here for each
    # joint from its rotation vector (the bound only skips work), and a joint is rewritten when its spring moves
    rng = np.random.default_rng(7)
    n = 2000
    laws = JointLaws(np.full((n, 3), LIMIT), np.full((n, 3), 2.0), np.full((n, 3), 40.0), 0.15, np.ones((n, 3)))
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    rot_a = rotvec_to_matrix(rng.normal(size=(n, 3)))
    rot_b = rot_a @ rotvec_to_matrix(axis * rng.uniform(0.0, 0.4, n)[:, None])
    omega_a, omega_b = rng.uniform(-3.5, 3.5, (n, 3)), rng.uniform(-3.5, 3.5, (n, 3))
    k_now, off_now = np.full((n, 3), 2.0), np.zeros((n, 3))
    was_stiff = rng.random(n) < 0.1
    k_now[was_stiff], off_now[was_stiff] = 30.0, 0.05
    active = rng.random(n) < 0.9
    changed, k, off = relinearized(laws, rot_a, rot_b, omega_a, omega_b, active, 0.01, k_now, off_now)

    rel = np.einsum("nji,njk->nik", rot_a, rot_b)
    theta = matrix_to_rotvec(rel)
    theta_next = theta + (np.einsum("nij,nj->ni", rel, omega_b) - omega_a) * 0.01
    near = active & ((np.abs(theta) > 0.255) | (np.abs(theta_next) > 0.255)).any(axis=1)
    k_law, off_law = laws.k_soft.copy(), np.zeros((n, 3))
    k_law[near], off_law[near] = linearize(JointLaws(laws.limit_rad[near], laws.k_soft[near], laws.k_limit[near],
                                                     0.15, laws.damping[near]), theta[near], theta_next[near])
    assert 0.2 * n < near.sum() < 0.8 * n  # both kinds, many of each
    assert np.array_equal(k, k_law) and np.array_equal(off, off_law)
    moved = (np.abs(k_law - k_now) > 0.02 * k_now).any(axis=1) | (np.abs(off_law - off_now) > 0.005).any(axis=1)
    assert np.array_equal(changed, moved)
