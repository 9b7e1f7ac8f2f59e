"""The shipped main scenario, scenarios/paper_test.toml (the README's first command), run whole: its time for
throughput is the feed plus the last fish's ride down the line, worked out from the belts' lengths and speeds."""

from __future__ import annotations

from pathlib import Path

import pytest

from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

PAPER = Path(__file__).parents[1] / "scenarios" / "paper_test.toml"


@pytest.fixture(scope="module")
def paper_run():
    sc = load_scenario(PAPER)
    return sc, run_scenario(sc, PAPER)


def test_the_paper_test_meets_its_bounds_and_loses_no_fish(paper_run) -> None:
    sc, result = paper_run
    assert result.status == "ok", result.error
    assert result.kpis["fish_in"] == sc.fish.count == 18 and result.kpis["lost"] == 0
    assert result.expect_ok, [e for e in result.expect if not e.ok]


def test_time_for_throughput_is_the_feed_plus_the_last_fishs_ride_at_belt_speed(paper_run) -> None:
    """T runs from the first drop to the moment the last fish clears the outfeed beam: the feed (17 intervals)
    plus the last fish's ride from where it was dropped to the beam, at each belt's speed.  A fish slips a
    little when dropped and at each transfer (it lags the belt), and clears the beam with its tail, up to
    half a length after its middle: both only add time."""
    sc, result = paper_run
    belts = sc.line.conveyors
    speeds = [sc.fmu[0].parameters[f"speed_{k + 1}"] for k in range(len(belts))]
    last = max(result.fish, key=lambda f: f.drop_t_s)
    first = min(result.fish, key=lambda f: f.drop_t_s)
    feed_s = last.drop_t_s - first.drop_t_s
    beam = next(p for p in sc.line.photoeyes if p.id == sc.kpi.outfeed_photoeye)
    ride_s = (belts[0].x_start_m + belts[0].length_m - last.drop_x_m) / speeds[0]
    ride_s += sum(b.length_m / v for b, v in zip(belts[1:-1], speeds[1:-1]))
    ride_s += (beam.x_m - belts[-1].x_start_m) / speeds[-1]
    t = result.kpis["throughput_time_s"]
    assert t >= feed_s + ride_s
    # the tail's half length at the outfeed's speed, and slip at the drop and at three transfers, a few tenths of a
    # second each: 3 s would be a fish held up
    assert t <= feed_s + ride_s + 0.5 * last.length_m / speeds[-1] + 3.0
