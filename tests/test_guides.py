"""Side guides as polylines (``[line.guides]``): a funnel that narrows the line from 0.5 to 0.25 m centres the
fish and none crosses it; a bad polyline is refused naming its key; straight guides are what they were."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from plant.contract.line import Line
from plant.errors import InputError
from plant.sim.plant import Plant
from plant.sim.state import FishStatus
from plant.validation import validate
from tests.chromium import CHROMIUM, Browser
from tests.plant_helpers import fish

from fishfmu import commands

needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM}: `apt-get install chromium`")

FUNNEL = {"left": [[0.8, 0.25], [1.8, 0.125]], "right": [[0.8, -0.25], [1.8, -0.125]]}


def funnel_line(guides: dict = FUNNEL, **extra) -> Line:
    return Line.model_validate({
        "guide_width_m": 0.5, "guides": guides,
        "conveyors": [{"id": "c1", "x_start_m": 0.0, "length_m": 3.2, "width_m": 0.5, "z_top_m": 0.0}], **extra})


def test_the_guides_are_the_polylines_and_straight_on_beyond_them():
    left, right = funnel_line().guide_y_at([0.0, 0.8, 1.3, 1.8, 3.0])
    assert left.tolist() == [0.25, 0.25, 0.1875, 0.125, 0.125] and right.tolist() == [-0.25, -0.25, -0.1875, -0.125, -0.125]
    straight = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 3.2, "width_m": 0.5, "z_top_m": 0.0}]})
    assert [v.tolist() for v in straight.guide_y_at([0.0, 3.0])] == [[0.25, 0.25], [-0.25, -0.25]]


@pytest.mark.parametrize("y0", [0.15, -0.15])
def test_a_fish_in_a_funnel_is_centred_and_never_crosses_a_guide(y0: float):
    line = funnel_line()
    plant = Plant(line, [fish("f1", 0.6, x_m=0.45, y_m=y0)])
    worst_m, last = -np.inf, None
    for _ in range(900):  # 9 s at 0.3 m/s: through the funnel to the end of the belt
        plant.step({"c1": 0.3})
        if plant.state.status[0] != FishStatus.ON_LINE:
            if last is None:
                continue  # not dropped yet
            break  # gone past the end
        p = plant.state.body_poses()[0]
        left, right = line.guide_y_at(p[:, 0])
        worst_m = max(worst_m, float(np.max(np.maximum(p[:, 1] - left, right - p[:, 1]))))
        last = p
    assert worst_m < 0.0, f"a body centre {worst_m * 1e3:.1f} mm beyond a guide"
    assert last is not None and last[:, 0].min() > 1.8  # all of it past the funnel's end
    assert np.abs(last[:, 1]).max() < 0.125  # between the narrow guides


@pytest.mark.parametrize("guides, where", [
    ({"left": [[1.0, 0.2], [0.5, 0.1]], "right": [[0.0, -0.25]]}, "line.guides.left[1]"),
    ({"left": [[1.0, 0.3]], "right": [[0.0, -0.25]]}, "line.guides.left[0]"),
    ({"left": [[1.0, 0.02]], "right": [[1.0, -0.02]]}, "line.guides"),
])
def test_a_bad_polyline_is_refused_naming_its_key(guides: dict, where: str):
    data = funnel_line().model_dump()
    data["guides"] = guides
    with pytest.raises(InputError) as err:
        validate(Line, data, prefix="line")
    assert where in str(err.value)


@needs_chromium
def test_the_replay_draws_the_funnel_where_the_line_has_it(tmp_path):
    """A short dumped run on the paper's line with a funnel on its second belt: the replay page's guides follow the
    polylines as the plant's do (the page draws its walls from the same interpolation)."""
    paper = Path(__file__).parents[1] / "scenarios" / "paper_dump.toml"
    text = paper.read_text()
    at = text.index("[[line.conveyors]]")
    funnel = ('[line.guides]\nleft = [[2.2, 0.25], [3.2, 0.15]]\nright = [[2.2, -0.25], [3.2, -0.15]]\n\n'
              '[[line.cameras]]\nid = "cam"\nx_start_m = 5.2\nx_end_m = 6.1\n\n')
    scenario = tmp_path / "funnel.toml"
    scenario.write_text(text[:at] + funnel + text[at:])
    done = commands.run(scenario, tmp_path / "out", {"fish.count": 4, "run.duration_s": 8.0, "expect": {}},
                        report=False, replay=True)
    assert done.result.status == "ok" and done.replay is not None
    line = done.result.scenario.line
    browser = Browser()
    try:
        browser.open(done.replay.as_uri())
        browser.eval("window.replay.ready")
        xs = [0.5, 2.2, 2.7, 3.2, 5.0]
        drawn = [browser.eval(f"window.replay.guideY({x})") for x in xs]
    finally:
        browser.close()
    left, right = line.guide_y_at(xs)
    assert np.allclose(drawn, np.column_stack([left, right]), atol=1e-12)
    assert drawn[2] == pytest.approx([0.2, -0.2])  # half-way down the funnel


OFF_CENTRE = {"line.guides.left": [[0.0, -0.05]], "line.guides.right": [[0.0, -0.25]]}


def test_fish_are_dropped_into_an_off_centre_lane_and_none_leaves_it():
    """Guides at y = -0.05 and -0.25 m: the lane is 0.2 m wide about y = -0.15 m.  A fish of 0.42 .. 0.75 m lying on
    its side is at most 0.187 m tall (the regression at 0.75 m), so each is dropped with its footprint inside
    -0.25 .. -0.05 (they were dropped about y = 0, outside it, and the first 'left the line sideways')."""
    from fishfmu.cosim.build import scenario_fish
    from fishfmu.scenario.schema import load_scenario

    sc = load_scenario(Path("scenarios/paper_dump.toml"), OFF_CENTRE | {"fish.count": 6, "fish.yaw_spread_deg": 0.0})
    fishes = scenario_fish(sc)
    for f in fishes:  # heading along the line (no yaw spread): across, it spans its height about drop_y_m
        assert -0.25 <= f.drop_y_m - 0.5 * f.height_m and f.drop_y_m + 0.5 * f.height_m <= -0.05
    plant = Plant(sc.line, [dataclasses.replace(f, drop_t_s=0.05 + 0.6 * i) for i, f in enumerate(fishes)])
    while plant.t_s < 4.0 - 1e-9:  # stopped belts: all of them dropped and settled (no run failure)
        plant.step({c.id: 0.0 for c in sc.line.conveyors})
    s = plant.state
    assert np.all(s.status == FishStatus.ON_LINE)
    on = s.on_line_bodies()
    assert np.all((s.pos[on, 1] > -0.25 - 0.05) & (s.pos[on, 1] < -0.05 + 0.05))  # bodies' centres, spheres' slack


def test_a_lane_too_narrow_for_the_fish_at_the_infeed_is_refused_naming_the_guides():
    from fishfmu.scenario.schema import load_scenario

    narrow = {"line.guides.left": [[0.0, -0.12]], "line.guides.right": [[0.0, -0.25]]}  # 0.13 m for fish up to 0.187 m tall
    with pytest.raises(InputError, match="lane between the guides all along the infeed .* 0.130 m wide") as err:
        load_scenario(Path("scenarios/paper_dump.toml"), narrow)
    assert err.value.where == "line.guides"
