"""The plant's health checks on hand-made states (no Exudyn): :func:`plant.sim.health.check_health`
(non-finite, too fast, outside the guides, through a belt, but not over the end drum) and the
energy watch with its spring reserve worked out by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from plant.errors import SimulationError
from plant.sim.health import EnergyWatch, check_health, floor_below, spring_reserve_j
from plant.contract.line import Line
from plant.sim.state import FishStatus, PlantOutputs, PlantState

WAITING, ON_LINE, LEFT = FishStatus.WAITING, FishStatus.ON_LINE, FishStatus.LEFT

# two belts, x 0..2 at z 0 and x 2..4 stepped down to z -0.1; guides at y = +-0.25
LINE = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
    {"id": "c2", "x_start_m": 2.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": -0.1}]})
IDS = ["f1", "f2"]
T = 1.23


def two_fish(**body_of_f2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """f1 lying on c1 at x 0.5..0.9, f2 on c1 at x 1.2..1.6, both moving at 0.3 m/s along x; one body
    of f2 (its third) changed by ``pos=`` / ``vel=``."""
    x = np.r_[np.linspace(0.5, 0.9, 5), np.linspace(1.2, 1.6, 5)]
    pos = np.stack([x, np.zeros(10), np.full(10, 0.02)], axis=1)
    vel = np.tile([0.3, 0.0, 0.0], (10, 1))
    if "pos" in body_of_f2:
        pos[7] = body_of_f2["pos"]
    if "vel" in body_of_f2:
        vel[7] = body_of_f2["vel"]
    return pos, vel, np.repeat([0, 1], 5)


def check(**body_of_f2) -> None:
    pos, vel, fish_of = two_fish(**body_of_f2)
    check_health(pos, vel, fish_of, IDS, LINE, T)


def test_fish_lying_on_the_belts_are_healthy():
    check()
    check_health(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=int), IDS, LINE, T)


@pytest.mark.parametrize("body", [{"pos": [1.4, np.nan, 0.02]}, {"vel": [0.3, np.inf, 0.0]}])
def test_non_finite_state_names_the_fish(body):
    with pytest.raises(SimulationError, match="fish 'f2' has non-finite position or velocity") as info:
        check(**body)
    assert info.value.time_s == T


def test_faster_than_25_mps_is_a_blow_up():
    check(vel=[15.0, 20.0, 0.0])  # exactly 25 m/s: allowed
    with pytest.raises(SimulationError, match=r"numerical blow-up: fish 'f2' moves at 25\.6 m/s"):
        check(vel=[16.0, 20.0, 0.0])  # sqrt(656) = 25.61 m/s


def test_body_outside_the_guides():
    check(pos=[1.4, -0.29, 0.02])  # guides at 0.25, 0.05 m tolerance
    with pytest.raises(SimulationError, match=r"fish 'f2' left the line sideways \(y = -0\.310 m, guides at \+-0\.25 m\)"):
        check(pos=[1.4, -0.31, 0.02])
    check(pos=[4.05, 0.6, -0.3])  # past the end of the line: leaving it, not checked


def test_body_below_a_belt_fell_through():
    # middle of c1 (top at 0): tolerance 0.08 m
    check(pos=[1.4, 0.0, -0.07])
    with pytest.raises(SimulationError, match=r"fish 'f2' fell through a belt \(z = -0\.090 m at x = 1\.400 m\)"):
        check(pos=[1.4, 0.0, -0.09])
    # over the step between the belts the floor is the lower one, -0.1: down to -0.18 is fine
    assert floor_below(LINE, np.array([1.85, 1.95, 2.05, 2.5])).tolist() == [0.0, -0.1, -0.1, -0.1]
    check(pos=[1.95, 0.0, -0.17])
    with pytest.raises(SimulationError, match="fell through a belt"):
        check(pos=[2.5, 0.0, -0.19])


def test_body_hanging_over_the_end_drum_is_not_an_error():
    # the line ends at x = 4.0: a fish leaving it over the last drum hangs far below the belt top
    check(pos=[3.95, 0.0, -0.6])
    check(pos=[3.91, 0.0, -0.6])
    check(pos=[4.0, 0.0, -0.6])
    check(pos=[4.3, 0.0, -2.0])
    # clear of the drum (more than 0.1 m before the end) it went through the belt
    with pytest.raises(SimulationError, match=r"fell through a belt \(z = -0\.600 m at x = 3\.850 m\)"):
        check(pos=[3.85, 0.0, -0.6])


# ---- the energy watch --------------------------------------------------------------------------
G = 9.81
BODY_KG = 0.4
FISH_KG = 5 * BODY_KG  # 2 kg


def watched_plant(n_fish: int = 1) -> SimpleNamespace:
    """A plant made by hand: n fish of five 0.4 kg bodies (no rotational inertia), all in the system,
    waiting to be dropped; :func:`snapshot` publishes its state as the plant would."""
    return SimpleNamespace(n_fish=n_fish, status=np.full(n_fish, WAITING, dtype=np.int8),
                           pos=np.zeros((5 * n_fish, 3)), vel=np.zeros((5 * n_fish, 3)), t_s=0.0)


def snapshot(plant: SimpleNamespace, speed_mps: float = 0.0, load_force_n: float = 0.0) -> PlantState:
    """What EnergyWatch reads: the hand-made plant's state, with belt c1 at ``speed_mps`` pushing the
    fish with ``load_force_n``."""
    n = plant.n_fish
    member = np.arange(n)
    outputs = PlantOutputs(plant.t_s, {"c1": speed_mps}, {"c1": load_force_n}, {"c1": 0.0}, {})
    return PlantState(t_s=plant.t_s, fish_ids=tuple(f"f{k + 1}" for k in range(n)), status=plant.status.copy(),
                      member=member, fish_of_body=np.repeat(member, 5), pos=plant.pos.copy(),
                      rot=np.tile(np.eye(3), (5 * n, 1, 1)), vel=plant.vel.copy(), omega_local=np.zeros((5 * n, 3)),
                      body_mass_kg=np.full(5 * n, BODY_KG), body_inertia=np.zeros((5 * n, 3)),
                      fish_mass_kg=np.full(n, FISH_KG), gravity_mps2=np.array([0.0, 0.0, -G]), outputs=outputs)


def move(plant: SimpleNamespace, fish: int, z: float, vx: float) -> None:
    """Every body of the fish at height z moving at vx."""
    b = slice(5 * fish, 5 * fish + 5)
    plant.pos[b, 2] = z
    plant.vel[b, 0] = vx



def test_spring_reserve_is_8_j_plus_half_a_joule_per_kg():
    assert spring_reserve_j(0.0) == 8.0
    assert spring_reserve_j(FISH_KG) == 9.0
    assert spring_reserve_j(3 * FISH_KG) == 11.0


def test_energy_gained_within_the_reserve_passes_and_beyond_it_raises():
    plant = watched_plant()
    watch = EnergyWatch()
    watch.check(snapshot(plant), 0.01)  # nobody on the line
    plant.status[0] = ON_LINE  # dropped at rest at z = 0: E = 0
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == 0.0
    # 0.5 * 2 kg * (2.9 m/s)^2 = 8.41 J from nowhere: below the 9 J reserve
    move(plant, 0, 0.0, 2.9)
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == pytest.approx(8.41)
    assert watch.worst_ratio == pytest.approx(8.41 / 9.0)
    # 0.5 * 2 * 3.1^2 = 9.61 J: beyond it
    move(plant, 0, 0.0, 3.1)
    plant.t_s = 0.04
    with pytest.raises(SimulationError, match=r"gained 9\.6 J more energy than the belts supplied \(allowed 9\.0 J "
                                              r"for the springs\), most of it fish 'f1' \(\+9\.6 J since its lowest\)") as info:
        watch.check(snapshot(plant), 0.01)
    assert info.value.time_s == 0.04


def test_belt_work_and_falling_are_sources_of_energy():
    plant = watched_plant()
    watch = EnergyWatch()
    plant.status[0] = ON_LINE
    move(plant, 0, 1.0, 0.0)  # enters 1 m up: brings m g h = 19.62 J
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == 0.0
    # falls 1 m: v = sqrt(2 g h); kinetic energy from potential, nothing gained
    move(plant, 0, 0.0, np.sqrt(2 * G))
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == pytest.approx(0.0, abs=1e-9)
    # a belt at 2 m/s pushing with 1000 N for 0.01 s does 20 J of work: 19.62 J + 20 J on the fish
    # is 0 in excess; 8 J more is still within the reserve
    v = np.sqrt(2 * (2 * G + 20.0 + 8.0) / FISH_KG)
    move(plant, 0, 0.0, v)
    watch.check(snapshot(plant, 2.0, 1000.0), 0.01)
    assert watch.last_excess_j == pytest.approx(8.0)


def test_dissipated_energy_cannot_come_back():
    plant = watched_plant()
    watch = EnergyWatch()
    plant.status[0] = ON_LINE
    move(plant, 0, 1.0, 0.0)  # enters with 19.62 J
    watch.check(snapshot(plant), 0.01)
    move(plant, 0, 0.0, 0.0)  # landed and came to rest: 19.62 J dissipated
    watch.check(snapshot(plant), 0.01)
    # springs back up 0.5 m: 9.81 J, half of what it had, but more than the 9 J reserve from nowhere
    move(plant, 0, 0.5, 0.0)
    with pytest.raises(SimulationError, match=r"gained 9\.8 J .*allowed 9\.0 J"):
        watch.check(snapshot(plant), 0.01)


def test_reserve_grows_with_the_mass_on_the_line():
    # f3 gains 0.5 * 2 kg * (3.25 m/s)^2 = 10.5625 J from nowhere
    three, two = watched_plant(3), watched_plant(2)
    three.status[:] = ON_LINE
    two.status[:] = ON_LINE
    w3, w2 = EnergyWatch(), EnergyWatch()
    w3.check(snapshot(three), 0.01)
    w2.check(snapshot(two), 0.01)
    move(three, 2, 0.0, 3.25)
    move(two, 1, 0.0, 3.25)
    w3.check(snapshot(three), 0.01)  # three fish, 6 kg: reserve 8 + 3 = 11 J
    assert w3.last_excess_j == pytest.approx(10.5625)
    with pytest.raises(SimulationError, match=r"gained 10\.6 J .*allowed 10\.0 J.*fish 'f2'"):
        w2.check(snapshot(two), 0.01)  # two fish, 4 kg: reserve 10 J


def test_a_fish_leaving_the_line_takes_its_energy_with_it():
    plant = watched_plant(3)
    watch = EnergyWatch()
    plant.status[:2] = ON_LINE
    watch.check(snapshot(plant), 0.01)
    plant.status[2] = ON_LINE
    move(plant, 2, 1.0, 0.0)  # f3 enters 1 m up with 19.62 J
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == pytest.approx(0.0)
    plant.status[2] = LEFT  # ... and leaves with it: the bound is back to 0
    watch.check(snapshot(plant), 0.01)
    assert watch.last_excess_j == pytest.approx(0.0)
    # f1 and f2, 4 kg: reserve 10 J; f2 gains 0.5 * 2 * 3.2^2 = 10.24 J, which the 19.62 J f3
    # brought would have covered had it stayed
    move(plant, 1, 0.0, 3.2)
    with pytest.raises(SimulationError, match=r"gained 10\.2 J .*allowed 10\.0 J.*fish 'f2'"):
        watch.check(snapshot(plant), 0.01)
