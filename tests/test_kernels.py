"""The plant's C kernels (plant.sim.kernels) against their numpy references, to the bit: a run's results must not
depend on which computes them (the diagnose benchmark and every recorded figure were made with the references).
Random and edge-case inputs (angles at the small-angle switch and near half a turn, joints at every part of their
law, bodies at the edge of a beam's neighbourhood, non-finite and out-of-bounds states), and a plant run stepped
both ways."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from plant.sim import kernels
from plant.errors import SimulationError
from plant.sim.health import _all_clear, _line_bounds, all_clear_on_line, check_health
from plant.sim.joints import JointLaws, relinearized
from plant.sim.rotations import rotvec_to_matrix
from plant.sim.sensors import beams_blocked, outline_reach_m

RNG_SEED = 20261201


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def random_rotvecs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Rotation vectors of every size the plant meets: zero, around the small-angle switch (1e-6 rad), up to past a
    full turn, and near half a turn."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.concatenate([np.zeros(5), 10.0 ** rng.uniform(-9, -5, n // 4), rng.uniform(0.0, 7.0, n // 2),
                            np.pi + rng.uniform(-2e-3, 2e-3, n - 5 - n // 4 - n // 2)])
    return axis * angle[:, None]


def test_rotation_matrices_are_rodrigues_formula_to_the_bit():
    rng = np.random.default_rng(RNG_SEED)
    coords = np.hstack([rng.normal(size=(4000, 3)), random_rotvecs(rng, 4000)])  # (n, 6), as the plant reads a body
    got = kernels.rotation_matrices(coords)
    assert same_bits(got, rotvec_to_matrix(coords[:, 3:]))  # a view, as the plant took it before
    assert np.allclose(got @ got.transpose(0, 2, 1), np.eye(3), atol=1e-12)  # and they are rotations


def random_laws(rng: np.random.Generator, n: int) -> JointLaws:
    limit = rng.uniform(0.05, 0.8, (n, 3))
    k_limit = rng.uniform(1.0, 60.0, (n, 3))
    return JointLaws(limit, k_limit * rng.uniform(0.01, 0.34, (n, 3)), k_limit, 0.15, np.ones((n, 3)))


def joint_states(rng: np.random.Generator, n_fish: int, bodies_per_fish: int, bend_rad: float):
    """Bodies of ``n_fish`` chained fish, each joint bent about a random axis by up to ``bend_rad``, turning."""
    n_bodies = n_fish * bodies_per_fish
    rot = rotvec_to_matrix(rng.normal(size=(n_bodies, 3)) * 2.0)
    for f in range(n_fish):  # each body the one before it turned by the joint's bend
        for b in range(1, bodies_per_fish):
            i = f * bodies_per_fish + b
            bend = rng.normal(size=3)
            rot[i] = rot[i - 1] @ rotvec_to_matrix((bend / np.linalg.norm(bend) * rng.uniform(0, bend_rad))[None])[0]
    vel = rng.normal(size=(n_bodies, 6)) * np.array([0.5, 0.5, 0.5, 8.0, 8.0, 8.0])
    joint_bodies = np.array([(f * bodies_per_fish + j, f * bodies_per_fish + j + 1) for f in range(n_fish)
                             for j in range(bodies_per_fish - 1)], dtype=np.int64)
    return np.ascontiguousarray(rot), vel, joint_bodies


@pytest.mark.parametrize("bend_rad", [0.05, 0.5, 1.2])
def test_the_joints_springs_are_the_laws_to_the_bit(bend_rad):
    rng = np.random.default_rng(RNG_SEED + int(bend_rad * 100))
    stiffened = unchanged = 0
    for _ in range(30):
        rot, vel, joint_bodies = joint_states(rng, 12, 4, bend_rad)
        n = len(joint_bodies)
        laws = random_laws(rng, n)
        active = rng.random(n) < 0.85
        k_now = np.where(rng.random((n, 1)) < 0.5, laws.k_soft, laws.k_soft * rng.uniform(0.5, 3.0, (n, 3)))
        offset_now = np.where(rng.random((n, 1)) < 0.5, 0.0, rng.normal(scale=0.01, size=(n, 3)))
        a, b = joint_bodies[:, 0], joint_bodies[:, 1]
        expected = relinearized(laws, rot[a], rot[b], vel[a, 3:], vel[b, 3:], active, 0.01, k_now, offset_now)
        got = kernels.relinearized(laws, rot, vel, joint_bodies, active, 0.01, k_now, offset_now)
        for g, e in zip(got, expected):
            assert same_bits(g, e)
        stiffened += int((got[1] > laws.k_soft).any(axis=1).sum())
        unchanged += int((~got[0]).sum())
    assert unchanged > 0 and (stiffened > 0 or bend_rad < 0.1)  # both kinds of joint were there


def test_a_joint_near_half_a_turn_is_left_to_the_reference():
    rng = np.random.default_rng(RNG_SEED)
    rot, vel, joint_bodies = joint_states(rng, 3, 4, 0.3)
    rot[5] = rot[4] @ rotvec_to_matrix(np.array([[0.0, np.pi - 1e-4, 0.0]]))[0]  # fish 1's joint 0: near pi
    laws = random_laws(rng, len(joint_bodies))
    k_now, offset_now, active = laws.k_soft.copy(), np.zeros((len(joint_bodies), 3)), np.ones(len(joint_bodies), bool)
    a, b = joint_bodies[:, 0], joint_bodies[:, 1]
    expected = relinearized(laws, rot[a], rot[b], vel[a, 3:], vel[b, 3:], active, 0.01, k_now, offset_now)
    got = kernels.relinearized(laws, rot, vel, joint_bodies, active, 0.01, k_now, offset_now)
    assert all(same_bits(g, e) for g, e in zip(got, expected))
    assert got[0][3]  # that joint is far past its limits: rewritten


BEAMS = np.array([[1.0, 0.02], [1.6, 0.05], [2.5, 0.0]])
SPAN = np.array([[0.3, -0.3], [0.25, -0.2], [0.3, -0.3]])


def test_the_beams_are_the_outline_test_to_the_bit():
    rng = np.random.default_rng(RNG_SEED)
    n_bodies, per_body = 40, 9
    model = SimpleNamespace(section_body=np.repeat(np.arange(n_bodies - 2), per_body),  # the last two: no outline
                            section_x=rng.uniform(-0.12, 0.12, (n_bodies - 2) * per_body),
                            section_half_len=rng.uniform(0.0, 0.04, (n_bodies - 2) * per_body),
                            section_radius=rng.uniform(0.005, 0.02, (n_bodies - 2) * per_body))
    reach = outline_reach_m(model) + 1e-9
    reach = np.pad(reach, (0, n_bodies - len(reach)))
    sections = (model.section_body, model.section_x, model.section_half_len, model.section_radius)
    seen = []
    for _ in range(400):
        beam = BEAMS[rng.integers(0, len(BEAMS), n_bodies)]
        # most bodies at the edge of their beam's neighbourhood along x, some anywhere
        edge = beam[:, 0] + rng.choice([-1.0, 1.0], n_bodies) * (np.resize(reach, n_bodies) + rng.normal(0, 0.01, n_bodies))
        x = np.where(rng.random(n_bodies) < 0.7, edge, rng.uniform(0.5, 3.0, n_bodies))
        pos = np.column_stack([x, rng.uniform(-0.35, 0.35, n_bodies), rng.uniform(-0.05, 0.08, n_bodies)])
        rot = np.ascontiguousarray(rotvec_to_matrix(rng.normal(size=(n_bodies, 3))))
        on = rng.random(n_bodies) < 0.8
        expected = beams_blocked(model, pos, rot, on, BEAMS, SPAN)
        assert same_bits(kernels.beams_blocked(pos, rot, on, reach, sections, BEAMS, SPAN), expected)
        seen.append(expected)
    assert 0.05 < np.mean(seen) < 0.95  # the poses both block and clear the beams


def test_the_health_checks_first_look_is_the_bounds_test_and_never_clears_what_the_full_check_stops():
    from plant.contract.line import Line
    line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}]})
    rng = np.random.default_rng(RNG_SEED)
    verdicts, stopped = [], 0
    for case in range(1200):
        n = 30
        pos = np.column_stack([rng.uniform(0, 2, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0.0, 0.3, n)])
        vel = rng.normal(size=(n, 6))
        on = rng.random(n) < 0.9
        i = rng.integers(n)
        # one body near or past a bound: the guide, below the belt, fast, not finite; or at an end of the checked
        # range (the line's start - 0.1 m, its end, 0.1 m before it) beside a guide or below the belt
        kind = case % 9
        if kind == 1:
            pos[i, 1] = 0.3 + rng.normal(0, 1e-9) * (case % 2)
        elif kind == 2:
            pos[i, 2] = -0.08 + rng.normal(0, 1e-3)
        elif kind == 3:
            vel[i, :3] = 25.0 / np.sqrt(3) + rng.normal(0, 1e-6)
        elif kind == 4:
            pos[i, rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf])
        elif kind == 5:
            vel[i, rng.integers(3)] = np.nan
        elif kind in (6, 7, 8):
            pos[i, 0] = rng.choice([-0.1, 2.0, 1.9]) + rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-12, -2)
            pos[i, 1 + (kind == 7)] = {6: 0.4, 7: -0.3, 8: -0.4}[kind]
            if kind == 7 and case % 2:  # another body of its fish (three bodies a fish) over the end drum
                pos[i - i % 3 + (i % 3 + 1) % 3, 0] = 1.95
        expected = _all_clear(pos[on], vel[on, :3], _line_bounds(line)) if on.any() else True  # none: nothing to fail
        got = all_clear_on_line(pos, vel, on, line)
        assert got == expected, case
        verdicts.append(got)
        if got and on.any():  # clear: the full check finds nothing
            check_health(pos[on], vel[on, :3], np.arange(n)[on] // 3, [f"f{k}" for k in range(n)], line, 0.0)
        elif on.any():
            try:
                check_health(pos[on], vel[on, :3], np.arange(n)[on] // 3, [f"f{k}" for k in range(n)], line, 0.0)
            except SimulationError:
                stopped += 1
    assert 0.3 < np.mean(verdicts) < 0.95 and stopped > 100


def test_a_plant_run_steps_the_same_with_the_references(monkeypatch):
    """Fish dropped in a pile past a photo-eye, stepped with the kernels and with the numpy references in their
    place: every body's state and every beam the same to the bit, step by step."""
    from plant.contract.line import Line
    from plant.fish.population import FishSpec
    from plant.sim import plant as plant_module, sensors

    line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 1.6, "width_m": 0.5, "z_top_m": 0.0},
        {"id": "c2", "x_start_m": 1.62, "length_m": 1.0, "width_m": 0.5, "z_top_m": -0.03}],
        "photoeyes": [{"id": "pe1", "x_m": 0.9, "z_m": 0.02}, {"id": "pe2", "x_m": 1.8, "z_m": -0.01}]})
    fish = [FishSpec(f"f{i}", 0.55 + 0.02 * i, 0.12, 0.06, 2.0 + 0.2 * i, 10.0, 0.05 * i, 0.5 + 0.05 * i,
                     0.03 * (-1) ** i, 0.1 * (-1) ** i, 0.12 + 0.05 * i) for i in range(6)]

    def run() -> list:
        p = plant_module.Plant(line, fish)
        trace = []
        for _ in range(120):
            out = p.step({"c1": 0.6, "c2": 0.8})
            trace.append((p.state.pos.copy(), p.state.rot.copy(), p.state.vel.copy(), dict(out.photoeyes)))
        return trace

    with_kernels = run()
    with monkeypatch.context() as m:  # each kernel replaced by its numpy reference
        m.setattr(plant_module, "rotation_matrices", lambda coords: rotvec_to_matrix(coords[:, 3:]))
        m.setattr(plant_module, "relinearized", lambda laws, rot, vel, jb, on, dt, k, off: relinearized(
            laws, rot[jb[:, 0]], rot[jb[:, 1]], vel[jb[:, 0], 3:], vel[jb[:, 1], 3:], on, dt, k, off))
        m.setattr(plant_module, "all_clear_on_line", lambda *a: False)  # the full check every step
        m.setattr(sensors.kernels, "beams_blocked", lambda pos, rot, on, reach, sections, beams, span: beams_blocked(
            SimpleNamespace(section_body=sections[0], section_x=sections[1], section_half_len=sections[2],
                            section_radius=sections[3]), pos, rot, on, beams, span))
        with_references = run()
    blocked_steps = sum(any(t[3].values()) for t in with_kernels)
    assert blocked_steps > 5  # the fish pass the eyes
    for (p1, r1, v1, e1), (p2, r2, v2, e2) in zip(with_kernels, with_references):
        assert same_bits(p1, p2) and same_bits(r1, r2) and same_bits(v1, v2) and e1 == e2


def test_a_kernel_given_the_wrong_arrays_refuses_them_instead_of_reading_past_them():
    from plant.sim import kernels_c
    rot = np.ascontiguousarray(np.repeat(np.eye(3)[None], 4, axis=0))
    rel, cos = np.empty((2, 3, 3)), np.empty(2)
    with pytest.raises(IndexError, match="joint 1 joins body 3 and 4 of 4"):
        kernels_c.joint_cosines(rot, np.array([[0, 1], [3, 4]]), rel, cos)
    with pytest.raises(ValueError, match="rel: dimension 0 is 2, expected 3"):
        kernels_c.joint_cosines(rot, np.array([[0, 1], [1, 2], [2, 3]]), rel, np.empty(3))
    with pytest.raises(TypeError, match="joint_bodies: expected 2 dimensions of 'q'"):
        kernels_c.joint_cosines(rot, np.array([[0.0, 1.0]]), rel[:1], cos[:1])
    with pytest.raises(TypeError, match="C-contiguous"):
        kernels_c.rotation_matrices(np.zeros((5, 6))[:, ::2], 0, np.empty((5, 3, 3)))
    with pytest.raises(ValueError, match="column"):
        kernels.rotation_matrices(np.zeros((5, 4)))  # no three columns from column 3
    with pytest.raises(TypeError, match="writable"):
        out = np.empty((5, 3, 3))
        out.setflags(write=False)
        kernels_c.rotation_matrices(np.zeros((5, 6)), 3, out)
