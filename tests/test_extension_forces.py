"""The extension forces as functions of a hand-made state (no Exudyn): adhesion between spheres of
different fish, and the friction level a fish takes from the direction it slips over its belt."""

from __future__ import annotations

import numpy as np
import pytest

from plant.fish.extensions import (FRICTION_LEVELS, Adhesion, DirectionFriction, adhesion_forces,
                              direction_friction_levels, friction_level)

ADHESION = Adhesion(force_n=2.0, range_m=0.004)


def test_touching_spheres_of_two_fish_attract_equal_and_opposite_along_their_centres():
    # sphere 0 on body 0 (fish 0), sphere 1 on body 5 (fish 1): surfaces 0.002 m apart, within range
    centres = np.array([[0.0, 0.0, 0.0], [0.0, 0.022, 0.0]])
    radii = np.array([0.01, 0.01])
    force = adhesion_forces(centres, radii, np.array([0, 5]), np.repeat([0, 1], 5), 10, ADHESION)
    assert force[0] == pytest.approx([0.0, 2.0, 0.0])
    assert force[5] == pytest.approx([0.0, -2.0, 0.0])
    assert np.count_nonzero(force) == 2


def test_spheres_out_of_range_or_of_one_fish_do_not_attract():
    radii = np.array([0.01, 0.01])
    far = np.array([[0.0, 0.0, 0.0], [0.0, 0.0250, 0.0]])  # 0.005 m apart > 0.004 m
    assert not adhesion_forces(far, radii, np.array([0, 5]), np.repeat([0, 1], 5), 10, ADHESION).any()
    close = np.array([[0.0, 0.0, 0.0], [0.0, 0.021, 0.0]])
    same_fish = np.array([0, 1])  # bodies 0 and 1 both belong to fish 0
    assert not adhesion_forces(close, radii, same_fish, np.repeat([0, 1], 5), 10, ADHESION).any()


def test_a_lone_sphere_feels_nothing():
    one = adhesion_forces(np.zeros((1, 3)), np.array([0.01]), np.array([0]), np.zeros(5, int), 5, ADHESION)
    assert one.shape == (5, 3) and not one.any()


DIRECTION = DirectionFriction(head=0.6, tail=1.8, across=1.2)
# one fish lying along +x: mid at 0, head-side spine point at +0.1, tail-side at -0.1
SPINE = np.array([[[0.0, 0.0], [0.1, 0.0], [-0.1, 0.0]]])


@pytest.mark.parametrize("velocity, multiplier", [
    ((0.5, 0.0), 0.6),    # slips head first over a belt at rest: along the scales
    ((-0.5, 0.0), 1.8),   # tail first: against the scales
    ((0.0, 0.5), 1.2),    # sideways
])
def test_the_friction_level_follows_the_direction_of_slip(velocity, multiplier):
    level = direction_friction_levels(SPINE, np.array([velocity]), np.array([0.0]), np.array([1.0]),
                                      np.array([friction_level(1.0)]), DIRECTION, 0.01)
    assert FRICTION_LEVELS[level[0]] == pytest.approx(multiplier)


def test_slip_is_relative_to_the_belt_and_mucus_scales_it():
    # the fish moves at 1.0 m/s on a belt at 1.5 m/s: it slips backwards, tail first
    level = direction_friction_levels(SPINE, np.array([[1.0, 0.0]]), np.array([1.5]), np.array([1.5]),
                                      np.array([0]), DIRECTION, 0.01)
    assert FRICTION_LEVELS[level[0]] == pytest.approx(1.8 * 1.5)


def test_a_fish_riding_with_its_belt_keeps_its_level():
    kept = np.array([17])
    level = direction_friction_levels(SPINE, np.array([[0.8, 0.0]]), np.array([0.8]), np.array([1.0]), kept,
                                      DIRECTION, 0.01)
    assert level[0] == 17


def test_a_friction_gradient_grades_the_bodies_from_head_to_fin_around_the_fish_level():
    from plant.fish.extensions import body_friction_levels
    level = int(friction_level(1.0))
    assert body_friction_levels(level, 0.0).tolist() == [level] * 5  # no gradient: the fish's level, untouched
    multipliers = FRICTION_LEVELS[body_friction_levels(level, 0.5)]
    assert multipliers.tolist() == pytest.approx([0.5, 0.75, 1.0, 1.25, 1.5])
    # around a fish at 1.2 (e.g. mucus): the same proportions of its multiplier
    assert FRICTION_LEVELS[body_friction_levels(int(friction_level(1.2)), -0.5)].tolist() == pytest.approx(
        [1.8, 1.5, 1.2, 0.9, 0.6])
