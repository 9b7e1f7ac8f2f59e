"""The model extensions (plant.fish.extensions) do what their physics says, checked against hand values."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.sim.simulate import simulate_plant
from tests.plant_helpers import fish, straight_line
from tests.test_plant_physics import G, speed_of


def slide_acceleration(params: PlantParams, yaw_rad: float, angle_deg: float) -> float:
    """Measured acceleration down an inclined, stopped belt (the line rising downstream: gravity tilted towards -x)."""
    params.incline_deg = angle_deg
    line = straight_line(("c1", 0.0, 6.0, 0.0))
    run = simulate_plant(line, [fish(x_m=5.0, yaw_rad=yaw_rad)], {"c1": 0.0}, 1.3, params=params,
                         stop_when_clear=False)
    tr = run.tracks
    v1, v2 = -speed_of(tr, 0.5, 0.7), -speed_of(tr, 1.1, 1.3)
    return (v2 - v1) / 0.6


@pytest.mark.parametrize("heading, factor_name", [(math.pi, "head"), (0.0, "tail")])
def test_direction_friction_makes_head_first_slide_easier_than_tail_first(heading, factor_name):
    params = PlantParams()
    params.extensions.direction_friction.head = 0.7
    params.extensions.direction_friction.tail = 1.4
    angle = 35.0
    mu = params.friction.fish_belt * getattr(params.extensions.direction_friction, factor_name)
    a = math.radians(angle)
    expected = G * (math.sin(a) - mu * math.cos(a))  # sliding towards -x: heading pi is head first
    assert slide_acceleration(params, heading, angle) == pytest.approx(expected, abs=0.15 * 3.0)


def test_mucus_friction_scales_friction_with_hours_post_mortem():
    params = PlantParams()
    params.extensions.mucus_friction.gain = -0.4
    params.extensions.mucus_friction.time_constant_h = 24.0
    f = fish()
    factor = 1.0 - 0.4 * (1.0 - math.exp(-f.hours_post_mortem / 24.0))
    angle = 28.0  # above the friction angle only once the mucus has changed it
    a = math.radians(angle)
    expected = G * (math.sin(a) - params.friction.fish_belt * factor * math.cos(a))
    assert expected > 0.5 and math.tan(a) < params.friction.fish_belt * 1.2
    assert slide_acceleration(params, 0.0, angle) == pytest.approx(expected, abs=0.3)


def test_rigor_mortis_stiffens_the_joints_by_its_index_of_the_hours_post_mortem():
    """The head over the end of a belt droops by the sag rule; at full rigor (stiffness x 4) a quarter as much."""
    from tests.test_fish_body import test_head_over_the_end_of_a_belt_droops_as_the_sag_rule_says as droop_test
    params = PlantParams()
    gain = 3.0
    params.extensions.rigor_mortis.stiffness_gain = gain
    params.extensions.rigor_mortis.peak_h = 24.0  # the test fish is 24 h post mortem: full rigor
    line = straight_line(("c1", 0.0, 1.5, 0.0))
    from plant.fish.fish_body import fish_geometry
    f0 = fish(length_m=0.6)
    g = fish_geometry(f0.length_m, f0.height_m, f0.width_m, f0.weight_kg)
    f = fish(length_m=0.6, x_m=1.5 - 0.035 - (g.mid_from_snout_m - g.joint_from_snout_m[0]))
    plant = Plant(line, [f], params)
    for _ in range(150):
        plant.step({"c1": 0.0})
    _, rot = plant.state.body_poses()
    rel = rot[0].T @ rot[1]
    bend = abs(math.degrees(math.atan2(rel[0, 2], rel[0, 0])))
    soft = params.joints.sag_fraction * 13.75
    assert bend == pytest.approx(soft / (1.0 + gain), rel=0.4)
    assert callable(droop_test)


def test_adhesion_holds_a_fish_on_top_of_another_on_a_slope():
    """Fish-on-fish friction (0.30) lets the upper fish slide down a 22 degree slope (tan 22 = 0.40)
    while the lower one holds on the belt (0.45); slime strong enough makes them move together."""
    angle = 22.0
    relative = {}
    for force in (0.0, 3.0):
        params = PlantParams()
        params.incline_deg = angle  # rising downstream
        params.extensions.adhesion.force_n = force
        line = straight_line(("c1", 0.0, 6.0, 0.0))
        lower = fish("low", x_m=3.0, t_s=0.02)
        upper = dataclasses.replace(fish("up", x_m=3.0, t_s=0.3), drop_z_m=0.005)
        run = simulate_plant(line, [lower, upper], {"c1": 0.0}, 1.5, params=params, stop_when_clear=False)
        tr = run.tracks[run.tracks.t_s >= 0.6]
        moved = {f: float(g.x_m.iloc[-1] - g.x_m.iloc[0]) for f, g in tr.groupby("fish_id")}
        relative[force] = moved["up"] - moved["low"]
    # without slime the upper fish slides over the lower: at least the distance of an effective friction
    # of 0.38 (the coefficient is 0.30; the rows of contact spheres interlock a little), 0.9 s from rest
    a = math.radians(angle)
    slide = 0.5 * G * (math.sin(a) - 0.38 * math.cos(a)) * 0.9**2
    assert relative[0.0] < -slide
    assert abs(relative[3.0]) < 0.01  # with slime they move together
