"""The plant's physics, checked against values worked out by hand from the parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant.fish.fish_body import FISH_MODELS
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.fish.population import PopulationSpec, sample_fish
from plant.sim.health import floor_below
from plant.sim.simulate import simulate_plant
from plant.sim.state import FishStatus
from tests.plant_helpers import fish, straight_line

G = 9.81


def speed_of(tracks, t0: float, t1: float) -> float:
    """Mean speed along x of the tracked mid-point between t0 and t1 (from positions, not samples)."""
    tr = tracks[(tracks.t_s >= t0) & (tracks.t_s <= t1)]
    return float((tr.x_m.iloc[-1] - tr.x_m.iloc[0]) / (tr.t_s.iloc[-1] - tr.t_s.iloc[0]))


def test_fish_reaches_belt_speed_and_moves_with_it():
    belt = 0.35
    line = straight_line(("c1", 0.0, 3.0, 0.0))
    run = simulate_plant(line, [fish(x_m=0.5)], {"c1": belt}, 2.0)
    mu = PlantParams().friction.fish_belt
    # from rest, Coulomb friction accelerates at mu g: belt speed after v / (mu g) = 0.08 s
    t_reach = belt / (mu * G)
    assert speed_of(run.tracks, 0.05 + 3 * t_reach + 0.2, 2.0) == pytest.approx(belt, rel=0.05)
    # and then it moves with the belt: no drift of the last second relative to the belt
    assert speed_of(run.tracks, 1.0, 2.0) == pytest.approx(belt, rel=0.02)
    assert run.tracks.y_m.abs().max() < 0.02


@pytest.mark.parametrize("below", [True, False])
def test_fish_on_inclined_stopped_belt_stays_below_friction_angle_and_slides_above(below):
    params = PlantParams()
    mu = params.friction.fish_belt
    friction_angle = math.degrees(math.atan(mu))  # 24.2 deg for mu = 0.45
    angle = friction_angle - 9.0 if below else friction_angle + 8.0
    params.incline_deg = angle  # the line rises downstream: gravity pulls towards -x, down the slope
    line = straight_line(("c1", 0.0, 4.0, 0.0))
    run = simulate_plant(line, [fish(x_m=2.5)], {"c1": 0.0}, 1.6, params=params, stop_when_clear=False)
    tr = run.tracks
    a = math.radians(angle)
    if below:
        # regularised Coulomb friction (proportional below v_reg): the fish creeps at the slip speed
        # at which mu N v/v_reg balances the slope force: v = v_reg tan(a) / mu, and does not accelerate
        v_creep = params.numerics.friction_regularization_mps * math.tan(a) / mu
        v = -speed_of(tr, 0.6, 1.6)
        assert v < 1.3 * v_creep
        assert -speed_of(tr, 1.1, 1.6) < 1.3 * v_creep  # not speeding up
    else:
        # sliding: a = g (sin a - mu cos a) down the slope (all bodies slide together)
        acc = G * (math.sin(a) - mu * math.cos(a))
        t1, t2 = 0.6, 1.4
        v1, v2 = -speed_of(tr, t1 - 0.1, t1 + 0.1), -speed_of(tr, t2 - 0.1, t2 + 0.1)
        assert (v2 - v1) / (t2 - t1) == pytest.approx(acc, rel=0.15)


def test_fish_crosses_onto_faster_belt_and_accelerates_as_friction_allows():
    slow, fast = 0.3, 0.9
    line = straight_line(("c1", 0.0, 2.0, 0.0), ("c2", 2.01, 2.5, -0.02))
    run = simulate_plant(line, [fish(x_m=1.2)], {"c1": slow, "c2": fast}, 5.0)
    tr = run.tracks
    assert speed_of(tr, 0.8, 1.6) == pytest.approx(slow, rel=0.05)
    on_fast = tr[tr.x_m > 2.01 + 0.5]  # the whole fish (0.6 m) is on the fast belt
    assert len(on_fast) > 10
    t_full = float(on_fast.t_s.iloc[0])
    assert speed_of(tr, t_full + 0.3, t_full + 0.8) == pytest.approx(fast, rel=0.05)
    # no faster than friction allows: the fast belt pulls at most mu m g, so the speed-up from
    # slow to fast takes at least (fast - slow) / (mu g)
    mu = PlantParams().friction.fish_belt
    t = tr.t_s.to_numpy()
    v = np.gradient(tr.x_m.to_numpy(), t)
    t_start = t[np.argmax(v > slow + 0.05)]
    t_done = t[np.argmax(v > fast - 0.05)]
    assert t_done - t_start >= 0.8 * (fast - slow) / (mu * G)
    # ... and the slip is not much slower than that either: done within the fish's transfer
    assert t_done - t_start < 0.6 / slow + 0.5


def test_belt_carries_the_fish_weight_and_feels_its_acceleration():
    belt = 0.5
    f = fish(x_m=1.0)
    line = straight_line(("c1", 0.0, 3.0, 0.0))
    plant = Plant(line, [f])
    masses, forces = [], []
    for _ in range(150):
        out = plant.step({"c1": belt})
        masses.append(out.belt_load_mass_kg["c1"])
        forces.append(out.belt_load_force_n["c1"])
    # resting: the belt carries the fish's weight
    assert np.mean(masses[-50:]) == pytest.approx(f.weight_kg, rel=0.05)
    # while the fish is accelerated from rest the belt feels m a = mu m g on average;
    # the impulse over the whole speed-up is m * belt speed
    impulse = float(np.sum(forces)) * 0.01
    assert impulse == pytest.approx(f.weight_kg * belt, rel=0.1)
    assert abs(np.mean(forces[-50:])) < 0.05 * f.weight_kg * G


def test_twenty_fish_dropped_in_bulk_stay_on_the_line():
    line = straight_line(("c1", 0.0, 2.0, 0.0), ("c2", 2.01, 1.5, -0.02), ("c3", 3.52, 1.5, -0.04))
    spec = PopulationSpec(count=20, drop_interval_s=0.15)
    rng = np.random.default_rng(7)
    fishes = sample_fish(spec, (0.0, 2.0), 0.25, rng)
    params = PlantParams()
    lowest: list[float] = []
    widest: list[float] = []

    def watch(plant: Plant) -> None:
        pos, _ = plant.state.body_poses()
        on = np.repeat(plant.status == FishStatus.ON_LINE, FISH_MODELS[params.fish_model])
        if np.any(on):
            p = pos[on]
            inside = p[:, 0] < line.x_end_m
            if np.any(inside):
                # away from belt ends a body lies on the belt; near them it may drape over the drum
                # down to the next belt, never below it
                lowest.append(float(np.min(p[inside, 2] - floor_below(line, p[inside, 0]))))
            widest.append(float(np.max(np.abs(p[:, 1]))))

    run = simulate_plant(line, fishes, {"c1": 0.3, "c2": 0.6, "c3": 1.0}, 6.0, params=params, on_step=watch,
                         stop_when_clear=False)
    assert run.t_end_s == pytest.approx(6.0)
    # body centres never below the lowest belt surface nearby (a body lies a sphere radius above it)
    assert min(lowest) > 0.0
    # and never beyond the guides (a body centre stays a sphere radius inside them)
    assert max(widest) < 0.5 * line.guide_width_m
    assert len(run.tracks.fish_id.unique()) == 20


def test_same_seed_gives_identical_tracks_and_sensors():
    line = straight_line(("c1", 0.0, 2.0, 0.0), ("c2", 2.01, 1.5, -0.02), photoeyes=(("pe", 2.2, 0.0),))
    spec = PopulationSpec(count=6, drop_interval_s=0.2)
    runs = [simulate_plant(line, sample_fish(spec, (0.0, 2.0), 0.25, np.random.default_rng(3)),
                           {"c1": 0.4, "c2": 0.9}, 4.0) for _ in range(2)]
    assert runs[0].tracks.equals(runs[1].tracks)
    assert runs[0].photoeyes.equals(runs[1].photoeyes)
    assert len(runs[0].photoeyes) > 0


def test_a_friction_gradient_moves_ground_at_a_transfer_from_the_end_that_slips_to_the_end_that_grips():
    """A fish taken over by a faster belt head first has its heavy front there first: in the model as shipped
    it comes up to speed well before one arriving tail first (0.25 m ahead 1.2 s after its mid-point crossed,
    measured).  Friction graded along the fish (head x0.4, fin x1.6) puts the slippery end on the fast belt
    for a head-first fish and the gripping one for a tail-first fish: the head-first fish loses ground, the
    tail-first one gains, and the gap narrows; the opposite gradient widens it."""
    slow, fast = 0.3, 0.9
    line = straight_line(("c1", 0.0, 2.0, 0.0), ("c2", 2.01, 2.5, -0.02))

    def progress(gradient: float, yaw_rad: float) -> float:
        params = PlantParams()
        params.friction.belt_gradient = gradient
        run = simulate_plant(line, [fish(x_m=1.3, yaw_rad=yaw_rad)], {"c1": slow, "c2": fast}, 4.5, params=params,
                             stop_when_clear=False)
        tr = run.tracks
        t_cross = float(tr.t_s[tr.x_m > 2.01].iloc[0])  # the mid-point reaches the fast belt
        return float(np.interp(t_cross + 1.2, tr.t_s, tr.x_m))

    gap = {g: progress(g, 0.0) - progress(g, math.pi) for g in (0.0, 0.6, -0.6)}  # head first minus tail first
    assert gap[0.0] > 0.15, gap
    assert gap[0.6] < gap[0.0] - 0.1, gap
    assert gap[-0.6] > gap[0.0] + 0.02, gap


def test_a_fish_leaving_a_slow_belt_over_its_end_tail_first_has_left_the_line_not_fallen_through_it():
    """At 0.1 m/s a fish riding tail first tips over the end drum and drops beside it, part of it not past
    the end: it has left the line (retired once far below), not gone through the belt (found by the paper
    study: a run stopped with 'fell through a belt' 1.5 m below the outfeed's end)."""
    line = straight_line(("c1", 0.0, 1.0, 0.0))
    run = simulate_plant(line, [fish(x_m=0.55, yaw_rad=math.pi)], {"c1": 0.1}, 12.0)
    assert run.fish_status is not None and run.fish_status[0] == FishStatus.LEFT
    assert run.t_end_s < 12.0  # cleared: the run stopped once the fish had gone


def test_stiff_joints_let_a_low_beam_flicker_under_a_fish_bridging_a_step():
    """Rigor's signature at the photo-eyes (issue 16): a beam 1.5 cm above a belt, 10 cm before its end,
    sees a fish while its front already reaches over the 2 cm step down to the next belt.  A limp fish
    drapes over the edge and its back stays on the belt: the beam is blocked from the fish's first moment
    there to its last.  With its joints stiffened (x9, and the range lost that goes with it) the fish
    pivots on the edge as a beam would, its back lifts, and the beam flickers under it.  Six fish of
    0.45-0.7 m, one at a time: the mean blocked share of their passages falls (measured: 0.98 limp, where
    one fish of six flickers; 0.87 at x3 and 0.89 at x9, where five of six do)."""
    from fishfmu.analysis.residuals import photoeye_passages

    line = straight_line(("c1", 0.0, 2.0, 0.0), ("c2", 2.01, 1.5, -0.02), ("c3", 3.52, 1.5, -0.04),
                         photoeyes=(("pe", 3.41, -0.005),))
    lengths = (0.45, 0.5, 0.55, 0.6, 0.65, 0.7)

    def blocked(stiffening: float) -> float:
        params = PlantParams()
        params.joints.stiffening = stiffening
        batch = [fish(f"f{i}", length_m=L, x_m=1.0, t_s=0.05 + 3.0 * i) for i, L in enumerate(lengths)]
        run = simulate_plant(line, batch, {"c1": 0.5, "c2": 0.8, "c3": 1.2}, 3.0 * len(lengths) + 6.0,
                             params=params, stop_when_clear=True)
        passages = photoeye_passages(run.tracks, run.photoeyes, run.fish, line)
        assert len(passages) == len(lengths)  # every fish passed the beam alone, along the line
        return float(passages["blocked"].mean())

    soft, stiff = blocked(0.0), blocked(8.0)
    assert soft > 0.95, soft
    assert stiff < soft - 0.02, (soft, stiff)
