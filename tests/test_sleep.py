"""Sleeping fish (plant.sim.sleep) against the fully integrated plant: a fish riding alone is carried
with its belt, woken before a belt speed change friction could not follow at ease, before a transfer,
and ends where the integrated fish ends."""

from __future__ import annotations

import numpy as np
import pytest

from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.sim.sleep import box_gap, riding
from tests.plant_helpers import fish, straight_line

LINE = straight_line(("c1", 0.0, 4.0, 0.0), ("c2", 4.01, 1.5, -0.02))


def _run(sleep: bool, speeds: list[tuple[float, float]], steps: int):
    params = PlantParams.model_validate({"numerics": {"sleep": sleep}})
    plant = Plant(LINE, [fish(x_m=0.5)], params)
    track, asleep = [], []
    for i in range(steps):
        t = i * 0.01
        v1 = [v for t0, v in speeds if t >= t0][-1]
        plant.step({"c1": v1, "c2": 1.0})
        s = plant.fish_state()
        track.append((s.x_m[0], s.y_m[0], s.yaw_rad[0]))
        asleep.append(bool(plant.state.asleep[0]) if plant.state.asleep is not None else False)
    return np.array(track), np.array(asleep), plant


def test_a_lone_fish_sleeps_on_a_steady_belt_and_rides_where_the_integrated_one_does():
    speeds = [(0.0, 0.4)]
    awake, _, _ = _run(False, speeds, 700)
    slept, asleep, plant = _run(True, speeds, 700)
    assert asleep[200:].mean() > 0.5  # carried for most of its ride once it has settled
    assert np.nanmax(np.abs(slept[:, 0] - awake[:, 0])) < 0.002
    assert np.nanmax(np.abs(slept[:, 1] - awake[:, 1])) < 0.002
    assert plant.fish_steps_asleep > 0


def test_a_sleeping_fish_wakes_for_a_sudden_stop_and_slides_as_the_integrated_one():
    speeds = [(0.0, 0.4), (3.0, 0.0)]  # a step change: far more than mu g per step
    awake, _, _ = _run(False, speeds, 450)
    slept, asleep, _ = _run(True, speeds, 450)
    assert asleep[250:299].all() and not asleep[300:310].any()
    assert np.nanmax(np.abs(slept[:, 0] - awake[:, 0])) < 0.002


def test_it_wakes_before_the_transfer_and_crosses_it_integrated():
    speeds = [(0.0, 0.8)]
    awake, _, _ = _run(False, speeds, 600)
    slept, asleep, _ = _run(True, speeds, 600)
    x = slept[:, 0]
    # awake once its front (0.3 m ahead of the mid point) is within 5 cm of c1's end, until wholly on c2
    assert asleep[x < 3.5].any() and not asleep[(x > 4.0 - 0.3 - 0.05 + 0.01) & (x < 4.3)].any()
    assert np.nanmax(np.abs(slept[:, 0] - awake[:, 0])) < 0.005


def test_riding_and_box_gaps_on_hand_made_values():
    vel = np.zeros((2, 5, 3))
    vel[:, :, 0] = 0.5
    vel[1, 2, 1] = 0.02  # one body of fish 1 slips sideways
    assert riding(vel, np.zeros((2, 5, 3)), np.full((2, 5), 0.5)).tolist() == [True, False]
    a = np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
    b = np.array([[[1.2, 0.0, 0.0], [2.0, 1.0, 1.0]], [[0.5, 0.5, 0.5], [0.6, 0.6, 0.6]]])
    assert box_gap(a, b)[0] == pytest.approx([0.2, -0.5])
