"""Inclined belts (``incline_deg``): a fish on a belt climbing below its friction angle rides with it; above it,
it slides back down against the belt.  Friction fish-belt 0.45 (the default): friction angle atan(0.45) = 24.2 deg.
The friction is regularised (``NumericsParams.friction_regularization_mps`` = 0.03 m/s), so below the friction angle a
fish creeps back at v_reg tan(a) / mu (docs/model.md): 0.012 m/s at 10 deg."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant.contract.line import Line
from plant.errors import InputError
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.validation import validate
from tests.plant_helpers import fish

MU = 0.45
V_REG = 0.03


def slope(incline_deg: float) -> Line:
    return Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 3.0, "width_m": 0.5, "z_top_m": 0.0, "incline_deg": incline_deg}]})


def ride(incline_deg: float, belt_mps: float, settle_s: float = 1.5, watch_s: float = 2.0) -> tuple[float, float]:
    """(the fish's mean speed along the slope over ``watch_s`` after ``settle_s``, its height above the belt then)."""
    line = slope(incline_deg)
    plant = Plant(line, [fish("f1", 0.6, x_m=1.0)])
    for _ in range(round(settle_s / 0.01)):
        plant.step({"c1": belt_mps})
    x0 = plant.state.fish_poses().x_m[0]
    for _ in range(round(watch_s / 0.01)):
        plant.step({"c1": belt_mps})
    s = plant.state.fish_poses()
    along = (s.x_m[0] - x0) / math.cos(math.radians(incline_deg)) / watch_s
    return along, s.z_m[0] - line.z_top_at(s.x_m[0])


def test_below_the_friction_angle_a_fish_rides_up_with_the_belt():
    speed, height = ride(10.0, 0.2)
    creep = V_REG * math.tan(math.radians(10.0)) / MU
    assert speed == pytest.approx(0.2 - creep, abs=0.003)  # measured: within 1e-6 m/s
    assert 0.0 < height < 0.05  # lying on the slope, not thrown off it


def test_above_the_friction_angle_a_fish_slides_back_down_the_moving_belt():
    """Sliding, it feels friction mu g cos(a) against gravity's g sin(a) along the slope: it accelerates down the
    belt at g (sin a - mu cos a), 1.08 m/s^2 at 30 deg, whichever way the belt runs."""
    a = math.radians(30.0)
    plant = Plant(slope(30.0), [fish("f1", 0.6, x_m=2.4)])
    along = []
    for k in range(round(1.0 / 0.01)):
        plant.step({"c1": 0.1})
        if k + 1 in (40, 60, 80):  # 0.4, 0.6, 0.8 s: landed, sliding, not yet at the infeed's end plate
            along.append(plant.state.fish_poses().x_m[0] / math.cos(a))
    s0, s1, s2 = along
    assert s2 < s1 < s0  # going down while the belt goes up
    accel = (s2 - 2 * s1 + s0) / 0.2**2
    assert accel < 0.0
    # the friction the slide shows, mu = (g sin a + accel) / (g cos a): the difference of two near forces amplifies
    # any error of it about 8x in the acceleration; measured 0.4565 for the joined fish at 2 ms with spheres three
    # radii apart (1.4 % high, the acceleration 5 % low), 0.4502 for the paper's fish at 1.25 ms
    assert (9.81 * math.sin(a) + accel) / (9.81 * math.cos(a)) == pytest.approx(MU, rel=0.02)


def test_on_a_flat_belt_it_rides_at_the_belt_speed():
    speed, _ = ride(0.0, 0.2)
    assert speed == pytest.approx(0.2, abs=0.005)


def test_an_incline_sets_where_the_belt_ends_and_the_next_must_start_below_it():
    line = slope(10.0)
    assert line.conveyors[0].z_end_m == pytest.approx(3.0 * math.tan(math.radians(10.0)))
    assert line.z_top_at(1.5) == pytest.approx(1.5 * math.tan(math.radians(10.0)))
    data = line.model_dump()
    data["conveyors"].append({"id": "c2", "x_start_m": 3.01, "length_m": 1.0, "width_m": 0.5, "z_top_m": 0.6})
    with pytest.raises(InputError, match="is above where 'c1' ends"):
        validate(Line, data, prefix="line")
    data["conveyors"][1]["z_top_m"] = 0.5
    assert np.isclose(validate(Line, data, prefix="line").z_range_m[1], 0.529, atol=1e-3)


def test_the_whole_line_tilted_up_by_plant_incline_deg_pulls_fish_back_upstream_as_a_climbing_belt_does():
    """``plant.incline_deg = +a`` tilts the line so that it rises downstream, as a conveyor's ``incline_deg = +a``:
    gravity along the line is -g sin(a), g cos(a) into the belt.  On a flat, stopped belt tilted by 30 deg (above the
    friction angle) a fish slides upstream at g (sin a - mu cos a) = 9.81 (0.5 - 0.45 x 0.866) = 1.08 m/s^2, as it does
    down a stopped belt inclined 30 deg in a level line (there along the slope)."""
    a = math.radians(30.0)
    params = PlantParams()
    params.incline_deg = 30.0
    flat = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 3.0, "width_m": 0.5, "z_top_m": 0.0}]})
    tilted = Plant(flat, [fish("f1", 0.6, x_m=2.4)], params=params)
    assert tilted.state.gravity_mps2 == pytest.approx([-9.81 * math.sin(a), 0.0, -9.81 * math.cos(a)])
    climbing = Plant(slope(30.0), [fish("f1", 0.6, x_m=2.4)])
    travelled = []
    for plant, scale in ((tilted, 1.0), (climbing, 1.0 / math.cos(a))):
        x = []
        for k in range(round(0.8 / 0.01)):
            plant.step({"c1": 0.0})
            if k + 1 in (40, 60, 80):
                x.append(plant.state.fish_poses().x_m[0] * scale)
        travelled.append(x)
    for x0, x1, x2 in travelled:
        acc = ((x2 - x1) - (x1 - x0)) / 0.2 ** 2
        assert x2 < x1 < x0  # upstream, down the slope
        assert -acc == pytest.approx(9.81 * (math.sin(a) - MU * math.cos(a)), rel=0.05)
