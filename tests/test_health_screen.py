"""The health check's quick screen (every step, from the positions' bounding box and the top speed) lets the full
check see every failure: states just inside and just past each bound, worked out by hand, on funnel guides, an
inclined belt and two lines in turn."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant.contract.line import Line
from plant.errors import SimulationError
from plant.sim.health import check_health

# funnel: the guides close in from y = +-0.4 at x = 0 to +-0.2 at x = 2 (interpolated between); one flat belt
FUNNEL = Line.model_validate({"guide_width_m": 0.8, "guides": {"left": [[0.0, 0.4], [2.0, 0.2]],
                                                               "right": [[0.0, -0.4], [2.0, -0.2]]},
                              "conveyors": [{"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.8,
                                             "z_top_m": 0.0}]})
# one belt rising 10 degrees over 1 m from z 0: its top at x is x tan 10 deg
INCLINE = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 1.0, "width_m": 0.5, "z_top_m": 0.0, "incline_deg": 10.0},
    {"id": "c2", "x_start_m": 1.0, "length_m": 1.0, "width_m": 0.5, "z_top_m": math.tan(math.radians(10.0))}]})
NARROW = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}]})
WIDE = Line.model_validate({"guide_width_m": 1.0, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 1.0, "z_top_m": 0.0}]})


def check(line: Line, xyz, v=(0.3, 0.0, 0.0)) -> None:
    """One fish of two bodies: one at ``xyz`` moving at ``v``, the other lying still mid-line at (0.5, 0, 0.02)."""
    pos = np.array([[0.5, 0.0, 0.02], xyz], dtype=float)
    vel = np.array([[0.0, 0.0, 0.0], v], dtype=float)
    check_health(pos, vel, np.array([0, 0]), ["f1"], line, 1.0)


@pytest.mark.parametrize("x, y_guide", [(0.5, 0.35), (1.8, 0.22)])  # the left guide there: 0.4 - 0.1 x
def test_a_body_past_a_funnel_guide_by_more_than_5_cm_is_outside_and_one_short_of_it_is_not(x, y_guide):
    check(FUNNEL, (x, y_guide + 0.049, 0.02))
    check(FUNNEL, (x, -y_guide - 0.049, 0.02))
    with pytest.raises(SimulationError, match="left the line sideways"):
        check(FUNNEL, (x, y_guide + 0.051, 0.02))
    with pytest.raises(SimulationError, match="left the line sideways"):
        check(FUNNEL, (x, -y_guide - 0.051, 0.02))


def test_the_speed_limit_is_25_mps_along_any_direction():
    check(FUNNEL, (1.0, 0.0, 0.02), v=(0.0, 14.0, 20.0))  # 24.4 m/s
    with pytest.raises(SimulationError, match="moves at 25.1 m/s"):
        check(FUNNEL, (1.0, 0.0, 0.02), v=(15.0, 0.0, 20.1))  # 25.08 m/s


def test_a_body_more_than_8_cm_below_the_inclined_belt_fell_through_it():
    top = 0.5 * math.tan(math.radians(10.0))  # the belt's top at x = 0.5: 88 mm
    check(INCLINE, (0.5, 0.0, top - 0.079))  # 9 mm above the lowest belt top (z 0 at x = 0)
    with pytest.raises(SimulationError, match="fell through a belt"):
        check(INCLINE, (0.5, 0.0, top - 0.081))


@pytest.mark.parametrize("body", [(1.0, float("nan"), 0.02), (1.0, 0.0, float("inf"))])
def test_a_non_finite_position_is_a_blow_up(body):
    with pytest.raises(SimulationError, match="non-finite"):
        check(FUNNEL, body)


def test_each_line_is_checked_against_its_own_guides_when_lines_alternate():
    for _ in range(2):
        with pytest.raises(SimulationError, match="left the line sideways"):
            check(NARROW, (1.0, 0.32, 0.02))  # past the narrow line's guide at 0.25 by 7 cm
        check(WIDE, (1.0, 0.32, 0.02))  # 18 cm inside the wide one's
