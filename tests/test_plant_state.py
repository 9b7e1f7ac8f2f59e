"""The state the plant publishes after each step (:class:`plant.sim.state.PlantState`, ``plant.state``):
read-only, a true snapshot (later steps do not change it), consistent with the physics, and enough
for the energy watch without the plant."""

from __future__ import annotations

import numpy as np
import pytest

from plant.errors import SimulationError
from plant.fish.fish_body import FISH_MODELS
from plant.sim.health import EnergyWatch
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.sim.state import FishStatus, PlantOutputs, PlantState
from tests.plant_helpers import fish, straight_line

G = 9.81
BELT_MPS = 0.35
DROP_T_S = 0.05
ARRAYS = ("status", "member", "fish_of_body", "pos", "rot", "vel", "omega_local", "body_mass_kg", "body_inertia",
          "fish_mass_kg", "gravity_mps2")


def belt_plant(**fish_kw) -> Plant:
    """One 2 m belt, photo-eye pe1 at x = 1.5 m, one 0.6 m fish dropped at 0.05 s flat from 1 cm
    above the belt at x = 0.6 m."""
    line = straight_line(("c1", 0.0, 2.0, 0.0), photoeyes=(("pe1", 1.5, 0.015),))
    return Plant(line, [fish("f01", t_s=DROP_T_S, **fish_kw)])


def test_state_before_the_first_step_is_at_rest():
    plant = belt_plant()
    s = plant.state
    assert s.t_s == 0.0 and s.fish_ids == ("f01",)
    assert s.status.tolist() == [FishStatus.WAITING]
    assert s.outputs == PlantOutputs(0.0, {"c1": 0.0}, {"c1": 0.0}, {"c1": 0.0}, {"pe1": False})
    assert s.fish_mass_kg[0] == pytest.approx(fish().weight_kg, rel=0.05)


def test_the_snapshot_arrays_cannot_be_written():
    plant = belt_plant()
    for _ in range(20):
        plant.step({"c1": BELT_MPS})
    s = plant.state
    assert len(s.pos) == FISH_MODELS[PlantParams().fish_model]  # one fish's bodies
    for name in ARRAYS:
        arr = getattr(s, name)
        assert not arr.flags.writeable, name
        with pytest.raises(ValueError, match="read-only"):
            arr[...] = 0
    with pytest.raises(AttributeError):
        s.t_s = 1.0  # type: ignore[misc]
    # the plant's own status moves on; the snapshot's is a copy of it
    assert s.status is not plant.status and not np.shares_memory(s.status, plant.status)


def test_a_snapshot_does_not_change_with_later_steps():
    plant = belt_plant()
    for _ in range(20):
        plant.step({"c1": BELT_MPS})
    s = plant.state
    pos, vel, status, t = s.pos.copy(), s.vel.copy(), s.status.copy(), s.t_s
    for _ in range(10):
        plant.step({"c1": BELT_MPS})
    assert plant.state is not s and plant.state.t_s == pytest.approx(t + 0.1)
    assert not np.array_equal(plant.state.pos, pos)  # the fish moved on ...
    np.testing.assert_array_equal(s.pos, pos)        # ... the old snapshot did not
    np.testing.assert_array_equal(s.vel, vel)
    np.testing.assert_array_equal(s.status, status)


def test_a_fish_dropped_on_a_running_belt_is_on_the_line_and_rides_at_belt_speed():
    plant = belt_plant()
    mu = PlantParams().friction.fish_belt
    # dropped from 1 cm: it lands within sqrt(2 h / g) = 0.045 s; from rest, Coulomb friction
    # accelerates it at mu g: belt speed after v / (mu g) = 0.08 s; allow three times that
    t_reach = BELT_MPS / (mu * G)
    t_check = DROP_T_S + 0.05 + 3 * t_reach + 0.2
    speeds = []
    while plant.t_s < t_check - 1e-9:
        out = plant.step({"c1": BELT_MPS})
        s = plant.state
        assert s.outputs is out and s.t_s == plant.t_s
        speeds.append(float(np.mean(s.vel[:, 0])) if s.status[0] == FishStatus.ON_LINE else np.nan)
    s = plant.state
    assert FishStatus(int(s.status[0])) is FishStatus.ON_LINE
    assert s.member.tolist() == [0] and s.fish_of_body.tolist() == [0] * FISH_MODELS[PlantParams().fish_model]
    # every body moves with the belt along x, hardly across or up and down
    np.testing.assert_allclose(s.vel[:, 0], BELT_MPS, rtol=0.05)
    assert np.all(np.abs(s.vel[:, 1:]) < 0.05 * BELT_MPS)
    # ... and got there from rest: still slow just after the drop
    assert speeds[int(round(DROP_T_S / 0.01))] < 0.5 * BELT_MPS
    # on the belt: bodies above its top (z = 0), less than the fish's height above it
    assert np.all(s.pos[:, 2] > 0.0) and np.all(s.pos[:, 2] < fish().height_m)


def test_state_outputs_are_the_belt_load_of_the_step():
    # a fish resting on the belt: the belt carries its weight (what resim logs from state.outputs)
    plant = belt_plant()
    for _ in range(80):
        plant.step({"c1": BELT_MPS})
    masses = []
    for _ in range(20):
        plant.step({"c1": BELT_MPS})
        masses.append(plant.state.outputs.belt_load_mass_kg["c1"])
    assert np.mean(masses) == pytest.approx(float(plant.state.fish_mass_kg[0]), rel=0.05)


def test_the_energy_watch_follows_the_published_state_of_a_running_plant():
    plant = belt_plant()
    watch = EnergyWatch()
    for _ in range(60):
        plant.step({"c1": BELT_MPS})
        watch.check(plant.state, 0.01)
    s = plant.state
    # the fish's energy from the snapshot alone: kinetic (translation and rotation) plus potential
    e = EnergyWatch.fish_energy(s)
    m = s.body_mass_kg
    by_hand = float(np.sum(0.5 * m * np.sum(s.vel**2, axis=1) + 0.5 * np.sum(s.body_inertia * s.omega_local**2, axis=1)
                           - m * (s.pos @ s.gravity_mps2)))
    assert e[0] == pytest.approx(by_hand)
    assert 0.0 <= watch.worst_excess_j < 1.0


def hand_state(t_s: float, z_m: float, vx_mps: float, status: FishStatus = FishStatus.ON_LINE,
               belt_mps: float = 0.0, load_n: float = 0.0) -> PlantState:
    """One fish of five 0.4 kg bodies (no rotational inertia) at height z moving at vx, built by hand."""
    pos = np.zeros((5, 3))
    pos[:, 2] = z_m
    vel = np.zeros((5, 3))
    vel[:, 0] = vx_mps
    return PlantState(t_s=t_s, fish_ids=("hand",), status=np.array([status], dtype=np.int8), member=np.array([0]),
                      fish_of_body=np.zeros(5, dtype=np.int64), pos=pos, rot=np.tile(np.eye(3), (5, 1, 1)), vel=vel,
                      omega_local=np.zeros((5, 3)), body_mass_kg=np.full(5, 0.4), body_inertia=np.zeros((5, 3)),
                      fish_mass_kg=np.array([2.0]), gravity_mps2=np.array([0.0, 0.0, -G]),
                      outputs=PlantOutputs(t_s, {"c1": belt_mps}, {"c1": load_n}, {"c1": 0.0}, {}))


def test_the_energy_watch_works_from_a_snapshot_built_by_hand():
    watch = EnergyWatch()
    watch.check(hand_state(0.00, 0.0, 0.0, FishStatus.WAITING), 0.01)
    watch.check(hand_state(0.01, 0.5, 0.0), 0.01)                 # enters 0.5 m up: brings 9.81 J
    assert EnergyWatch.fish_energy(hand_state(0.01, 0.5, 0.0))[0] == pytest.approx(2.0 * G * 0.5)
    # a belt at 1 m/s pushing with 200 N for 0.01 s supplies 2 J: sqrt(2) m/s (2 J) is no excess
    watch.check(hand_state(0.02, 0.5, np.sqrt(2.0), belt_mps=1.0, load_n=200.0), 0.01)
    assert watch.last_excess_j == pytest.approx(0.0, abs=1e-9)
    # without the belt, 4 m/s (16 J) is 14 J from nowhere: beyond the 9 J reserve for 2 kg
    with pytest.raises(SimulationError, match=r"gained 14\.0 J .*allowed 9\.0 J.*fish 'hand'") as info:
        watch.check(hand_state(0.03, 0.5, 4.0), 0.01)
    assert info.value.time_s == pytest.approx(0.03)


def test_fish_status_keeps_the_ints_of_the_status_arrays():
    assert [int(s) for s in FishStatus] == [0, 1, 2, 3]  # poses.npz of earlier runs hold 0-2
    assert [s.name for s in FishStatus] == ["WAITING", "ON_LINE", "LEFT", "REJECTED"]
    assert np.array([0, 1, 2], dtype=np.int8)[1] == FishStatus.ON_LINE


def test_two_fish_with_one_id_are_refused_before_anything_is_built():
    # Given to the plant through the Python API, they simulated as two bodies under one name: their tracks,
    # passages and KPIs would have been read as one fish's.
    with pytest.raises(ValueError, match="fish id 'f01' is given to 2 fish"):
        Plant(straight_line(("c1", 0.0, 3.0, 0.0)), [fish("f01", x_m=1.0), fish("f02", x_m=2.0),
                                                    fish("f01", x_m=1.1, z_m=0.08)])


def _two_fish_state(t_s: float, vx_mps: tuple[float, float], body_on: np.ndarray, mass: np.ndarray,
                    belt_mps: float = 0.0, load_n: float = 0.0) -> PlantState:
    """Fish 1 and 3 of four in the system (slots in that order), five 0.4 kg bodies each at 0.5 m moving at vx
    each, the on-line mask and masses published read-only as the plant publishes them (the same objects while no
    fish comes or goes)."""
    pos = np.zeros((10, 3))
    pos[:, 2] = 0.5
    vel = np.zeros((10, 3))
    vel[:5, 0], vel[5:, 0] = vx_mps
    status = np.array([FishStatus.LEFT, FishStatus.ON_LINE, FishStatus.WAITING,
                       FishStatus.ON_LINE if body_on[0] else FishStatus.LEFT], dtype=np.int8)
    return PlantState(t_s=t_s, fish_ids=("a", "b", "c", "d"), status=status, member=np.array([3, 1]),
                      fish_of_body=np.repeat([3, 1], 5), pos=pos, rot=np.tile(np.eye(3), (10, 1, 1)), vel=vel,
                      omega_local=np.zeros((10, 3)), body_mass_kg=mass, body_inertia=np.zeros((10, 3)),
                      fish_mass_kg=np.full(4, 2.0), gravity_mps2=np.array([0.0, 0.0, -G]),
                      outputs=PlantOutputs(t_s, {"c1": belt_mps}, {"c1": load_n}, {"c1": 0.0}, {}), body_on=body_on)


def test_the_energy_watch_between_arrivals_keeps_the_same_account():
    """While no fish comes or goes the watch works on the system's fish alone (a run's hundreds of others take no
    part): the same excess, worked out here by hand, and a blow-up still named."""
    body_on, mass = np.ones(10, dtype=bool), np.full(10, 0.4)
    body_on.setflags(write=False)
    mass.setflags(write=False)
    watch = EnergyWatch()
    watch.check(_two_fish_state(0.00, (0.0, 0.0), body_on, mass), 0.01)  # both enter at rest 0.5 m up: 2 x 9.81 J
    assert watch.last_excess_j == pytest.approx(0.0, abs=1e-12)
    # fish 'd' at 1 m/s (1 J) and fish 'b' at 2 m/s (4 J); a belt supplies 200 N x 1 m/s x 0.01 s = 2 J: 3 J excess
    watch.check(_two_fish_state(0.01, (1.0, 2.0), body_on, mass, belt_mps=1.0, load_n=200.0), 0.01)
    assert watch._layout is not None  # the quick account was kept
    assert watch.last_excess_j == pytest.approx(3.0)
    assert watch.worst_ratio == pytest.approx(3.0 / (8.0 + 0.5 * 4.0))
    # the bound is the lower of what was allowed and what the fish hold: 2 x 9.81 + 2 J; at rest again 2 J below
    # it, and the bound falls to what they hold
    watch.check(_two_fish_state(0.02, (0.0, 0.0), body_on, mass), 0.01)
    assert watch.last_excess_j == pytest.approx(-2.0)
    # 'd' leaves (its bodies off the line): it takes its 9.81 J with it, no excess
    gone = np.repeat([False, True], 5)
    gone.setflags(write=False)
    watch.check(_two_fish_state(0.03, (0.0, 0.0), gone, mass), 0.01)
    assert watch.last_excess_j == pytest.approx(0.0, abs=1e-12)
    watch.check(_two_fish_state(0.04, (0.0, 0.0), gone, mass), 0.01)
    assert watch._layout is not None and watch.last_excess_j == pytest.approx(0.0, abs=1e-12)
    # 'b' at 5 m/s: 25 J against a 9 J reserve for its 2 kg, named as the fish that gained it
    with pytest.raises(SimulationError, match=r"gained 25\.0 J .*allowed 9\.0 J.*fish 'b' \(\+25\.0 J"):
        watch.check(_two_fish_state(0.05, (0.0, 5.0), gone, mass), 0.01)
