"""Re-linearising the joints each step (:func:`plant.sim.joints.relinearized`) on hand-made relative rotations:
a joint well inside its limits keeps its soft spring and is not rewritten; one bent past its soft zone, or running
into it within the step, gets the law's tangent and the offset that gives the exact torque now; a parked fish's
joints are left soft."""

from __future__ import annotations

import numpy as np

from plant.sim.joints import JointLaws, relinearized, torque
from plant.sim.rotations import rot_z

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
