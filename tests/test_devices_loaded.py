"""A pusher fired over and over on a loaded line (a stream of fish 0.2 m apart, each firing with neighbours lying just
upstream and just downstream of the paddle) and a diverter swung for every second fish of a stream: the fish the
device acts on leave through its opening and are counted by it; the others stay on the line; no fish goes through a
guide wall anywhere else (the run never fails)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plant.contract.devices import SIDE_CLEAR_M, device_shapes
from plant.contract.line import Line
from plant.sim.health import EnergyWatch
from plant.sim.plant import Plant
from plant.sim.state import FishStatus
from tests.plant_helpers import fish

DT_S = 0.01
SPEED_MPS = 0.8
LENGTH_M = 0.5
PITCH_M = 0.7            # fish 0.5 m long, 0.2 m apart: a loaded line
DROP_X_M = 0.3
INTERVAL_S = PITCH_M / SPEED_MPS   # 0.875 s between drops
N_FISH = 8


def line_with(device: dict, half_lane_m: float = 0.25) -> Line:
    guides = {"guides": {"left": [[0.0, half_lane_m]], "right": [[0.0, -half_lane_m]]}} if half_lane_m < 0.25 else {}
    return Line.model_validate(guides | {"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 2.2, "width_m": 0.5, "z_top_m": 0.0},
        {"id": "c2", "x_start_m": 2.21, "length_m": 1.5, "width_m": 0.5, "z_top_m": -0.02}], "devices": [device]})


def stream(n: int, interval_s: float) -> list:
    return [fish(f"f{k}", LENGTH_M, x_m=DROP_X_M, y_m=0.0, t_s=0.05 + interval_s * k) for k in range(n)]


def run(line: Line, command, t_end_s: float, n: int = N_FISH, interval_s: float = INTERVAL_S):
    """Both belts at SPEED_MPS; returns the plant and, per step, the mid-length points (n_fish, 3) and the bodies of
    the fish on the line (n, 3)."""
    plant = Plant(line, stream(n, interval_s))
    watch = EnergyWatch()
    mids, bodies = [], []
    while plant.t_s < t_end_s - 1e-9:
        plant.step({"c1": SPEED_MPS, "c2": SPEED_MPS}, {line.devices[0].id: command(plant.t_s)})
        watch.check(plant.state, DT_S)
        s = plant.state
        poses = s.fish_poses()
        mids.append(np.column_stack([poses.x_m, poses.y_m]))
        bodies.append(s.pos[s.on_line_bodies()].copy())
    return plant, np.array(mids), bodies


def assert_no_fish_through_a_wall(bodies, x_from: float, x_to: float, out_side: int, half_lane_m: float = 0.25) -> None:
    """Every body of a fish on the line within the guides (+-half_lane_m, a sphere's radius of slack as the health
    check allows), except beyond the guide on ``out_side`` over the opening and its chute, x_from .. x_to."""
    for pos in bodies:
        x, y = pos[:, 0], pos[:, 1]
        at_opening = (x >= x_from - 0.05) & (x <= x_to + 0.05) & (out_side * y > 0)
        assert np.all((np.abs(y) <= half_lane_m + 0.05) | at_opening)


def test_a_pusher_fired_at_every_second_fish_of_a_stream_pushes_those_out_and_lets_the_others_pass():
    pusher = {"id": "p", "kind": "pusher", "x_m": 1.0, "length_m": 0.8, "stroke_s": 0.3, "side": "right"}
    line = line_with(pusher)
    shape = device_shapes(line)[0]
    assert shape.opening == (-1, 0.85, 1.95)  # the paddle's 0.8 m and 0.15 m beyond each end
    # A fish reaches the belt's speed within about 0.2 s of landing (friction 0.45 g: 0.8 / 4.4 = 0.18 s, lagging
    # 0.07 m), so fish k is at x = 0.3 - 0.07 + 0.8 (t - t_k).  Fired at every third fish when its mid point is at
    # 1.4 m (1.1 m on: t_k + 1.46 s), that fish lies wholly in front of the paddle (1.15 .. 1.65 within 1.0 .. 1.8); the
    # fish before it is at 2.1 m (1.85 .. 2.35: past the paddle, beside the downstream end of the opening) and the one
    # after it at 0.7 m (0.45 .. 0.95: its head in the opening's upstream margin, not in front of the paddle).  Out 0.6
    # s, back in 0.3 s: meanwhile the belt brings that fish 0.7 m on, head to 1.65 m, into the paddle's stretch: the
    # shield holds it at 1.0 m until the paddle goes back (without the shield it ran in behind the paddle, which
    # pressed it through the guide on its way back), and it goes on beside the retreating paddle.  Held up there for
    # up to 0.8 s (0.64 m), it is past the paddle at the next firing, 2.6 s later, and so is the one after it.
    fire_s = [0.05 + INTERVAL_S * k + 1.46 for k in range(0, N_FISH, 3)]

    def command(t):
        return any(f <= t < f + 0.6 for f in fire_s)

    plant, mids, bodies = run(line, command, 12.0)   # the last fish reaches the line's end (3.71 m) at about 11 s
    s = plant.state
    for k, f in zip(range(0, N_FISH, 3), fire_s):
        i = int(round(f / DT_S)) - 1
        assert 1.3 < mids[i, k, 0] < 1.5 and 2.0 < mids[i, k - 1, 0] < 2.2 if k else True  # as worked out above
        assert 0.6 < mids[i, k + 1, 0] < 0.8
    assert [FishStatus(v).name for v in s.status] == (["REJECTED", "LEFT", "LEFT"] * 3)[:N_FISH]
    rejected = s.status == FishStatus.REJECTED
    assert list(s.rejected_by[rejected]) == [0, 0, 0] and s.outputs.device_rejected == {"p": 3}
    for k in np.flatnonzero(rejected):  # each pushed out to the right over the opening: last seen beyond the guide
        seen = mids[np.isfinite(mids[:, k, 0]), k]
        # beyond the guide (y = -0.25 m); it is taken once SIDE_CLEAR_M beyond, in the step after it was last seen
        assert seen[-1, 1] < -0.25 and 0.85 - 0.1 <= seen[-1, 0] <= 1.95 + 0.6
    assert_no_fish_through_a_wall(bodies, 0.85, 1.95, -1)
    # the paddle's own side (left) never had a body beyond its guide: nothing pressed through it on the way back
    assert max(float(p[:, 1].max()) for p in bodies if len(p)) < 0.30


@pytest.mark.parametrize("half_lane_m", [0.25, 0.15])
def test_a_diverter_swung_for_every_second_fish_of_a_stream_steers_those_out_and_lets_the_others_pass(half_lane_m):
    """In a lane as wide as the belt, and in one 0.3 m wide on the 0.5 m belt (as after a funnel: a fish steered out
    lands on the strip of belt beyond the guide; it was not counted out until 0.1 m beyond it, rode on outside the
    guide and failed the run).  Fish 0.9 m apart (1.4 m pitch, 1.75 s) and the arm (1.0 .. 1.8 m, pivot at 1.8 m, 45 deg: its free end swings
    from x = 1.0 to 1.8 - 0.8 cos 45 = 1.23 m, 0.57 m across: the whole lane) swung when fish k's head is at 0.85 m:
    the fish before it has its tail at 1.75 m, by the pivot (the arm 5 cm before its pivot moves 5 cm in, to y = -0.2
    or -0.1 m: clear of the fish, 0.12 m tall, lying on its side about y = 0), so the arm's free end, always ahead of fish k's head (1.0 .. 1.23 m against 0.85 .. 1.09 m over the 0.3 s
    swing), sweeps through an empty stretch.  Swung 1.2 s, back in 0.3 s: by then fish k+1's head is at 0.65 m, short
    of the arm (1.0 m), so it passes the arm at home: a guide.  Fish k: steered out to the right; fish k+1: on."""
    diverter = {"id": "d", "kind": "diverter", "x_m": 1.0, "length_m": 0.8, "stroke_s": 0.3, "side": "right",
                "travel_deg": 45.0}
    line = line_with(diverter, half_lane_m)
    interval_s = 1.4 / SPEED_MPS
    # fish k's head: 0.3 + 0.25 - 0.07 + 0.8 (t - t_k) = 0.85 m at t_k + 0.46 s
    swing_s = [0.05 + interval_s * k + 0.46 for k in range(0, 6, 2)]

    def command(t):
        return any(f <= t < f + 1.2 for f in swing_s)

    plant, mids, bodies = run(line, command, 13.5, n=6, interval_s=interval_s)
    s = plant.state
    for k, f in zip(range(0, 6, 2), swing_s):
        i = int(round(f / DT_S)) - 1
        assert 0.55 < mids[i, k, 0] < 0.65   # head at 0.85 m as worked out
    assert [FishStatus(v).name for v in s.status] == ["REJECTED", "LEFT"] * 3
    assert list(s.rejected_by) == [0, -1] * 3 and s.outputs.device_rejected == {"d": 3}
    for k in (0, 2, 4):  # out to the right, by the opening
        seen = mids[np.isfinite(mids[:, k, 0]), k]
        assert seen[-1, 1] < -half_lane_m - SIDE_CLEAR_M and 1.0 - 0.1 <= seen[-1, 0] <= 1.8 + 0.6
    assert_no_fish_through_a_wall(bodies, 1.0, 1.8, -1, half_lane_m)


def test_the_issues_diverter_toggled_every_4_s_in_funnel_incline_runs_through(tmp_path):
    """Issue 39: funnel_incline with a diverter (3.6 .. 4.2 m, left, 0.3 s) swung and put back every 4 s from 8 s failed
    at 20.35 s, 'f03' left the line sideways at x = 3.49 m: going out at the opening's upstream end, its tail swung
    round the guide's end.  It runs through now; the fish it counts are those it took off (all fish either out by
    it, past the outfeed or still on the line)."""
    from fishfmu import commands

    src = Path("scenarios/funnel_incline.toml").read_text()
    events = "".join(f'[[event]]\nt_s = {t}.0\ntarget = "plant.d.command"\naction = "override"\nvalue = {str(i % 2 == 0).lower()}\n\n'
                     for i, t in enumerate(range(8, 24, 4)))
    device = ('[[line.devices]]\nid = "d"\nkind = "diverter"\nx_m = 3.6\nlength_m = 0.6\nstroke_s = 0.3\n'
              'side = "left"\n\n')
    text = src.replace("[fish]", device + events + "[fish]", 1).replace(
        "[wiring]\n", '[wiring]\ninputs = { "plant.d.command" = false }\n', 1)
    scenario = tmp_path / "diverter.toml"
    scenario.write_text(text)
    done = commands.run(scenario, tmp_path / "out", {"run.duration_s": 22.0, "expect": {}}, report=False)
    assert done.result.status == "ok"
    k = done.result.kpis
    assert k["rejected"] == k["rejected_by"]["d"] >= 1
