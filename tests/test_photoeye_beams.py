"""Photo-eye beams against fish outlines: each beam is tested only against the bodies near it, and that
neighbourhood loses no fish (positions worked out by hand, and every pose of a seeded set against the test of
every cross-section against every beam)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from plant.sim.rotations import rot_z, rotvec_to_matrix
from plant.sim.sensors import beams_blocked, outline_reach_m, photoeyes_blocked

SPAN = np.array([[0.3, -0.3], [0.3, -0.3]])  # each beam from guide (y = 0.3) to guide (y = -0.3)
BEAMS = np.array([[1.0, 0.0], [2.5, 0.0]])   # (x, z) of two beams


def one_section_body(section_x_m: float, half_len_m: float, radius_m: float) -> SimpleNamespace:
    """A model of one body with one stadium cross-section ``section_x_m`` ahead of its centre."""
    return SimpleNamespace(section_body=np.array([0]), section_x=np.array([section_x_m]),
                           section_half_len=np.array([half_len_m]), section_radius=np.array([radius_m]))


def test_the_neighbourhood_reaches_as_far_as_the_outline_does():
    model = one_section_body(0.45, 0.1, 0.01)
    assert outline_reach_m(model).tolist() == [0.45 + 0.1 + 0.01]


def test_a_body_whose_outline_just_reaches_a_beam_blocks_it_from_the_edge_of_the_neighbourhood():
    model = one_section_body(0.45, 0.1, 0.01)
    on = np.array([True])
    # body x along the line, its cross-section across it: a disc of radius 0.01 around x = centre + 0.45 in x-z
    # centre 0.545 m before beam 1 (its reach 0.56 m): the disc's centre 5 mm from the beam, so it cuts it
    pos = np.array([[1.0 - 0.455, 0.0, 0.0]])
    assert beams_blocked(model, pos, np.eye(3)[None], on, BEAMS, SPAN).tolist() == [True, False]
    # 15 mm from the beam: clear
    pos = np.array([[1.0 - 0.465, 0.0, 0.0]])
    assert beams_blocked(model, pos, np.eye(3)[None], on, BEAMS, SPAN).tolist() == [False, False]
    # a body off the line blocks nothing
    pos = np.array([[1.0 - 0.455, 0.0, 0.0]])
    assert beams_blocked(model, pos, np.eye(3)[None], np.array([False]), BEAMS, SPAN).tolist() == [False, False]


def test_a_body_turned_across_the_line_blocks_by_the_end_of_its_cross_section():
    model = one_section_body(0.45, 0.1, 0.01)
    rot = rot_z(np.pi / 2)[None]  # body x -> world y, body y (the cross-section's long axis) -> world -x
    # the cross-section spans x = centre -+ 0.1 at y = centre + 0.45: its near end 5 mm past beam 2
    pos = np.array([[2.5 + 0.105, -0.4, 0.0]])
    assert beams_blocked(model, pos, rot, np.array([True]), BEAMS, SPAN).tolist() == [False, True]
    pos = np.array([[2.5 + 0.115, -0.4, 0.0]])  # 5 mm short of it
    assert beams_blocked(model, pos, rot, np.array([True]), BEAMS, SPAN).tolist() == [False, False]


def test_beams_see_what_every_cross_section_tested_against_every_beam_sees():
    rng = np.random.default_rng(43)
    n_bodies, per_body = 12, 8
    model = SimpleNamespace(section_body=np.repeat(np.arange(n_bodies), per_body),
                            section_x=rng.uniform(-0.12, 0.12, n_bodies * per_body),
                            section_half_len=rng.uniform(0.0, 0.04, n_bodies * per_body),
                            section_radius=rng.uniform(0.005, 0.02, n_bodies * per_body))
    seen = []
    for _ in range(300):
        pos = np.column_stack([rng.uniform(0.5, 3.0, n_bodies), rng.uniform(-0.3, 0.3, n_bodies),
                               rng.uniform(-0.05, 0.05, n_bodies)])
        rot = rotvec_to_matrix(rng.normal(size=(n_bodies, 3)))
        on = rng.random(n_bodies) < 0.8
        all_sections = on[model.section_body]
        b = model.section_body[all_sections]
        centres = pos[b] + rot[b][:, :, 0] * model.section_x[all_sections][:, None]
        expected = photoeyes_blocked(centres, rot[b][:, :, 1], model.section_half_len[all_sections],
                                     model.section_radius[all_sections], BEAMS, SPAN)
        got = beams_blocked(model, pos, rot, on, BEAMS, SPAN)
        assert got.tolist() == expected.tolist()
        seen.append(expected)
    assert 0 < np.mean(seen) < 1  # the poses both block and clear the beams
