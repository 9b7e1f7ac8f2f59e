"""Guide wear (``[plant.extensions.guide_wear]``): fish-guide friction rising along the line, in guide sections of
their own friction.  Checked as physics: a fish carried by a belt into a guide set across the lane at an angle slides
along it at the speed Coulomb friction at that x allows, worked out here from the belt's speed, the angle and the
friction coefficient."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant.contract.line import Line
from plant.sim.params import PlantParams
from plant.sim.simulate import simulate_plant
from tests.plant_helpers import fish

BELT_MPS = 0.3
ANGLE_DEG = 30.0
LINE_END_M = 3.2


def slanted_guide_line() -> Line:
    """One 3.2 m belt; the left guide turns across the lane at 30 deg from x = 0.8 m (to 0.12 m from the right one)."""
    x0 = 0.8
    x1 = x0 + 0.38 / math.tan(math.radians(ANGLE_DEG))
    return Line.model_validate({
        "guide_width_m": 0.5, "guides": {"left": [[x0, 0.25], [x1, -0.13]], "right": [[0.0, -0.25]]},
        "conveyors": [{"id": "c1", "x_start_m": 0.0, "length_m": LINE_END_M, "width_m": 0.5, "z_top_m": 0.0}]})


def sliding_along_the_guide(rise: float) -> tuple[float, float]:
    """(the fish's speed along the slanted guide while it lies against it [m/s], the mean x there)."""
    params = PlantParams()
    params.extensions.guide_wear.rise = rise
    run = simulate_plant(slanted_guide_line(), [fish(x_m=0.45, y_m=0.12)], {"c1": BELT_MPS}, 4.0, params=params,
                         stop_when_clear=False)
    tr = run.tracks
    # lying along the guide: its heading within 1.5 deg of the guide's, and still short of the narrow end
    along = tr[(np.abs(np.degrees(tr.yaw_rad) + ANGLE_DEG) < 1.5) & (tr.y_m > -0.08)]
    assert along.t_s.max() - along.t_s.min() > 0.6, "the fish did not slide along the guide long enough to measure"
    d = np.hypot(along.x_m.iloc[-1] - along.x_m.iloc[0], along.y_m.iloc[-1] - along.y_m.iloc[0])
    return float(d / (along.t_s.iloc[-1] - along.t_s.iloc[0])), float(along.x_m.mean())


def friction_from_sliding(u_mps: float) -> float:
    """The fish slides over the belt (full Coulomb friction, along its slip relative to the belt) and along the guide:
    across the guide the belt's pull is the guide's normal force N, along it the guide's friction mu N, so
    mu = (v cos a - u) / (v sin a) for a belt at v, a guide at a to the belt's motion and the fish at u along it."""
    a = math.radians(ANGLE_DEG)
    return (BELT_MPS * math.cos(a) - u_mps) / (BELT_MPS * math.sin(a))


@pytest.mark.parametrize("rise", [0.0, 2.0])
def test_a_fish_sliding_along_a_guide_is_held_back_by_the_guide_friction_at_its_x(rise: float):
    u, x = sliding_along_the_guide(rise)
    mu_guide = PlantParams().friction.fish_guide
    expected = mu_guide * (1.0 + rise * x / LINE_END_M)  # linear from the infeed (x = 0) to the outfeed end
    assert friction_from_sliding(u) == pytest.approx(expected, rel=0.12)


def test_the_sections_rise_linearly_from_the_infeed_to_the_outfeed():
    p = PlantParams()
    p.extensions.guide_wear.rise = 3.0
    edges, factors = p.extensions.guide_wear.sections(0.0, 1.0)
    assert edges.tolist() == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    assert factors.tolist() == pytest.approx([1.3, 1.9, 2.5, 3.1, 3.7])  # 1 + 3 x at the sections' middles
    assert not PlantParams().extensions.guide_wear.on and "guide_wear" not in PlantParams().extensions.active()
