"""The fish's bodies, masses, contact shape and joints, against the paper's tables and geometry."""

from __future__ import annotations

import numpy as np
import pytest

from plant.fish import fish_data
from plant.fish.fish_body import _spheres_overlap_at_limits, fish_geometry
from plant.fish.fish_data import length_regressions
from plant.sim.joints import JointLaws, joint_laws, linearize, tangent, torque
from plant.sim.model import prepare_fish
from plant.sim.params import PlantParams
from plant.sim.plant import Plant
from plant.sim.simulate import simulate_plant
from plant.fish.population import PopulationSpec, fish_size, sample_fish
from tests.plant_helpers import fish, straight_line

SIZES = [(0.42, 0.09, 0.04, 0.57), (0.60, 0.14, 0.065, 2.0), (0.68, 0.18, 0.08, 3.698)]


def test_regressions_reproduce_table1_within_its_own_scatter():
    t1 = fish_data.table1()
    reg = length_regressions()
    resid_h = t1.height_m - reg.height_m(t1.length_m)
    resid_w = np.log(t1.weight_kg) - np.log(reg.weight_kg(t1.length_m))
    assert abs(resid_h.mean()) < 1e-9  # least squares: residuals average out
    assert resid_h.std(ddof=2) == pytest.approx(reg.height_sd_m, rel=1e-6)
    assert np.all(np.abs(resid_w) < 3 * reg.weight_log_sd)


def test_sampled_fish_vary_around_the_regression_like_table1():
    rng = np.random.default_rng(0)
    reg = length_regressions()
    h = np.array([fish_size(0.6, rng)[0] for _ in range(4000)])
    assert h.mean() == pytest.approx(float(reg.height_m(0.6)), abs=0.002)
    assert h.std() == pytest.approx(reg.height_sd_m, rel=0.1)


@pytest.mark.parametrize("size", SIZES)
def test_body_masses_follow_table2_with_the_fin_raised_for_the_step(size):
    length, height, width, mass = size
    g = fish_geometry(length, height, width, mass)
    fractions = fish_data.table2()["fraction"].to_numpy()
    fractions = fractions / fractions.sum()
    masses = np.array([b.mass_kg for b in g.bodies])
    assert masses.sum() == pytest.approx(mass)
    # head, upper and lower body exactly as Table II; the fin raised to 6 %, taken from the tail
    assert masses[:3] / mass == pytest.approx(fractions[:3])
    assert masses[4] / mass == pytest.approx(0.06)
    assert masses[3] / mass == pytest.approx(fractions[3] - (0.06 - fractions[4]))


@pytest.mark.parametrize("size", SIZES)
def test_joined_fish_has_four_bodies_with_the_tail_and_fin_share_of_table2(size):
    length, height, width, mass = size
    g = fish_geometry(length, height, width, mass, fin_joined=True)
    t2 = fish_data.table2()
    fractions = (t2["weight_kg"] / t2["weight_kg"].sum()).to_numpy()  # sample #16's bodies, no mass floor
    masses = np.array([b.mass_kg for b in g.bodies])
    assert [b.name for b in g.bodies] == ["head", "upper_body", "lower_body", "tail"]
    assert len(g.joint_from_snout_m) == 3
    assert masses.sum() == pytest.approx(mass)
    assert masses[:3] / mass == pytest.approx(fractions[:3], abs=2e-3)
    assert masses[3] / mass == pytest.approx(0.228, abs=1e-3)  # (0.761 + 0.083) / 3.698 kg of Table II
    # the joined tail spans the paper's tail and fin: its centre of mass is theirs, weighted by Table II's masses
    paper = fish_geometry(length, height, width, mass)
    tail, fin = paper.bodies[3], paper.bodies[4]
    expected = (fractions[3] * tail.com_from_snout_m + fractions[4] * fin.com_from_snout_m) / (fractions[3] + fractions[4])
    assert g.bodies[3].com_from_snout_m == pytest.approx(expected, abs=1e-3 * length)
    assert (g.bodies[3].s_start, g.bodies[3].s_end) == (tail.s_start, 1.0)
    # the same contact spheres as the paper's fish, seen from the snout
    def from_snout(bodies):
        return sorted((round(b.com_from_snout_m - x, 9), round(y, 9), r) for b in bodies for x, y, r in b.spheres)
    assert from_snout(g.bodies) == from_snout(paper.bodies)
    # the joints left are Table III's first three
    p = PlantParams()
    laws = joint_laws(g, p.joints, p.numerics, 9.81)
    t3 = fish_data.table3()
    assert laws.limit_rad.shape == (3, 3)
    assert np.degrees(laws.limit_rad[:, 1]) == pytest.approx(t3.swing1_deg.to_numpy()[:3])
    assert np.degrees(laws.limit_rad[:, 2]) == pytest.approx(t3.swing2_deg.to_numpy()[:3])


def test_joined_fish_thin_bodies_get_the_full_sphere_implied_inertia_and_the_paper_fish_half():
    spec = fish(length_m=0.68, x_m=1.0)
    for model, share in (("joined4", 1.0), ("paper5", 0.5)):
        prep = prepare_fish(spec, PlantParams.model_validate({"fish_model": model}))
        tail = prep.geometry.bodies[-1]  # the joined tail with its fin; the paper's fin
        x = np.array([sx for sx, _, _ in tail.spheres])
        y = np.array([sy for _, sy, _ in tail.spheres])
        implied = share * tail.mass_kg * np.array([np.mean(x**2), np.mean(x**2 + y**2)])
        assert prep.inertias[-1][1:] == pytest.approx(np.maximum(tail.inertia_kgm2[1:], implied), rel=1e-12)
        assert np.all(prep.inertias[-1][1:] >= np.array(tail.inertia_kgm2[1:]))


@pytest.mark.parametrize("size", SIZES)
def test_contact_shape_is_as_long_high_and_thick_as_the_fish(size):
    length, height, width, mass = size
    g = fish_geometry(length, height, width, mass, sphere_spacing=2.0)
    pts = []
    for b in g.bodies:
        for x, y, r in b.spheres:
            d = b.com_from_snout_m - x  # distance from the snout
            pts.append((d - r, d + r, abs(y) + r, r))
    pts = np.array(pts)
    assert pts[:, 0].min() == pytest.approx(0.0, abs=0.01)          # reaches the snout
    assert pts[:, 1].max() == pytest.approx(length, abs=0.02)        # and the tail fin tip
    assert pts[:, 2].max() == pytest.approx(height / 2, rel=0.1)    # as high as the fish
    assert 2 * pts[:, 3].max() == pytest.approx(width, rel=0.05)     # as thick as the fish


@pytest.mark.parametrize("size", SIZES)
def test_neighbouring_bodies_spheres_do_not_touch_within_joint_limits(size):
    g = fish_geometry(*size, sphere_spacing=2.0)
    t3 = fish_data.table3()
    for j in range(4):
        xj = g.joint_from_snout_m[j]
        a, b = g.bodies[j], g.bodies[j + 1]
        pa = np.array([[xj - (a.com_from_snout_m - x), y, 0.0] for x, y, _ in a.spheres])
        pb = np.array([[xj - (b.com_from_snout_m - x), y, 0.0] for x, y, _ in b.spheres])
        # (relative to the joint, x towards the head)
        pa[:, 0], pb[:, 0] = -pa[:, 0], -pb[:, 0]
        limits = (np.radians(t3.swing1_deg[j]), np.radians(t3.swing2_deg[j]))
        assert not _spheres_overlap_at_limits(pa, np.array([r for *_, r in a.spheres]),
                                              pb, np.array([r for *_, r in b.spheres]), limits)


def test_joint_torque_is_smooth_and_stiffens_at_the_limit():
    law = JointLaws(limit_rad=np.full((1, 3), 0.3), k_soft=np.full((1, 3), 1.0), k_limit=np.full((1, 3), 30.0),
                    transition=0.15, damping=np.ones((1, 3)))
    th = np.linspace(-0.6, 0.6, 2401)[:, None].repeat(3, axis=1)
    laws = JointLaws(np.full_like(th, 0.3), np.full_like(th, 1.0), np.full_like(th, 30.0), 0.15, np.ones_like(th))
    tau = torque(laws, th)[:, 0]
    k = tangent(laws, th)[:, 0]
    # continuous torque and stiffness (C1): no jumps between neighbouring samples
    assert np.max(np.abs(np.diff(tau))) < 30.0 * (th[1, 0] - th[0, 0]) * 1.01
    assert np.max(np.abs(np.diff(k))) < 1.0
    # soft well inside, stiff well beyond, odd
    assert tangent(law, np.array([[0.1, 0.1, 0.1]]))[0, 0] == pytest.approx(1.0)
    assert tangent(law, np.array([[0.5, 0.5, 0.5]]))[0, 0] == pytest.approx(30.0)
    assert np.allclose(tau, -tau[::-1])
    # the derivative of the torque is the tangent stiffness
    assert np.allclose(np.gradient(tau, th[:, 0]), k, atol=0.3)


def test_linearisation_gives_the_exact_torque_now_and_is_stiff_ahead_of_a_limit():
    law = JointLaws(np.full((2, 3), 0.3), np.full((2, 3), 1.0), np.full((2, 3), 30.0), 0.15, np.ones((2, 3)))
    now = np.array([[0.2, 0.25, 0.4], [0.0, -0.1, -0.35]])
    ahead = now + np.array([[0.2, 0.0, 0.0], [0.0, 0.0, 0.0]])
    k, off = linearize(law, now, ahead)
    assert np.allclose(k * (now - off), torque(law, now))
    assert k[0, 0] == pytest.approx(30.0)  # running into the limit: already stiff
    assert k[1, 0] == pytest.approx(1.0)


def test_joint_laws_use_table3_limits_and_lock_the_twist_of_joints_1_to_3():
    p = PlantParams()
    g = fish_geometry(0.6, 0.14, 0.065, 2.0)
    laws = joint_laws(g, p.joints, p.numerics, 9.81)
    t3 = fish_data.table3()
    assert np.degrees(laws.limit_rad[:, 1]) == pytest.approx(t3.swing1_deg.to_numpy())
    assert np.degrees(laws.limit_rad[:, 2]) == pytest.approx(t3.swing2_deg.to_numpy())
    assert np.degrees(laws.limit_rad[3, 0]) == pytest.approx(22.5)
    assert np.all(laws.k_soft[:3, 0] == laws.k_limit[:3, 0])  # locked twist: stiff everywhere
    assert np.all(laws.k_soft[:, 1:] < laws.k_limit[:, 1:])


def test_head_over_the_end_of_a_belt_droops_as_the_sag_rule_says():
    """The joint stiffness is set so that the lighter side of a joint, held horizontally, bends
    ``sag_fraction`` of its limit under its own weight.  Lay a fish on a stopped belt with its
    head sticking out over the end: the head joint should bend by that much (the fish lies on
    its side, so bending to the side is bending down)."""
    params = PlantParams()
    line = straight_line(("c1", 0.0, 1.5, 0.0))
    f = fish(length_m=0.6, yaw_rad=0.0)
    g = fish_geometry(f.length_m, f.height_m, f.width_m, f.weight_kg, min_body_fraction=0.06)
    head_joint_from_mid = g.mid_from_snout_m - g.joint_from_snout_m[0]
    # joint 1 a drum radius inside the end of the belt: the head overhangs
    f = fish(length_m=0.6, x_m=1.5 - 0.035 - head_joint_from_mid)
    plant = Plant(line, [f], params)
    for _ in range(150):
        plant.step({"c1": 0.0})
    _, rot = plant.state.body_poses()
    rel = rot[0].T @ rot[1]
    bend = abs(np.degrees(np.arctan2(rel[0, 2], rel[0, 0])))  # rotation about the dorsal (y) axis
    expected = params.joints.sag_fraction * 13.75
    assert bend == pytest.approx(expected, rel=0.35)


def test_sampled_population_is_reproducible_and_inside_the_guides():
    spec = PopulationSpec(count=30)
    a = sample_fish(spec, (0.0, 2.0), 0.25, np.random.default_rng(5))
    b = sample_fish(spec, (0.0, 2.0), 0.25, np.random.default_rng(5))
    assert a == b
    for f in a:
        ext_y = 0.5 * f.length_m * abs(np.sin(f.drop_yaw_rad)) + 0.5 * f.height_m * abs(np.cos(f.drop_yaw_rad))
        ext_x = 0.5 * f.length_m * abs(np.cos(f.drop_yaw_rad)) + 0.5 * f.height_m * abs(np.sin(f.drop_yaw_rad))
        assert abs(f.drop_y_m) + ext_y <= 0.25
        assert f.drop_x_m - ext_x >= 0.0


def test_joined_fish_at_its_step_rests_on_the_belt_carried_at_belt_speed():
    """The four-body fish at 2.5 ms: it lies on its side with every body centre about half its thickness above the
    belt, the belt carries its weight, and it rides at the belt's speed."""
    belt = 0.4
    f = fish(length_m=0.6, x_m=1.0)
    params = PlantParams.model_validate({"fish_model": "joined4", "numerics": {"step_s": 0.0025}})
    plant = Plant(straight_line(("c1", 0.0, 3.0, 0.0)), [f], params=params)
    masses, xs = [], []
    for _ in range(150):
        out = plant.step({"c1": belt})
        masses.append(out.belt_load_mass_kg["c1"])
        xs.append(plant.state.fish_poses().x_m[0])
    s = plant.state
    assert s.bodies_per_fish == 4 and s.pos.shape == (4, 3)
    pos, rot = s.body_poses()
    assert pos.shape == (4, 3) and rot.shape == (4, 3, 3)
    assert np.mean(masses[-50:]) == pytest.approx(f.weight_kg, rel=0.05)
    assert (xs[-1] - xs[-51]) / 0.5 == pytest.approx(belt, rel=0.03)
    # on its side: the centres at half the local thickness, which is at most half the fish's width
    assert np.all(s.pos[:, 2] > 0.0) and np.all(s.pos[:, 2] < 0.5 * f.width_m + 0.005)


def test_joined_fish_poses_and_outlines_name_four_bodies_per_fish():
    """The recorded poses (what a run's poses.npz and the 3D replay read) have as many bodies as the model: the
    joined fish's outline sections end at its fin tip on its fourth body."""
    fishes = [fish("a", length_m=0.6, x_m=0.8), fish("b", length_m=0.5, x_m=2.0)]
    params = PlantParams.model_validate({"fish_model": "joined4", "numerics": {"step_s": 0.002}})
    run = simulate_plant(straight_line(("c1", 0.0, 3.0, 0.0)), fishes, {"c1": 0.3}, 0.5, params=params,
                         stop_when_clear=False, record_poses=True)
    p = run.poses
    assert p["pos"].shape[1:] == (8, 3) and p["quat"].shape[1:] == (8, 4)
    assert p["body_fish"].tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    # each fish's sections run from its snout (first body) to its fin tip (fourth body); a section's distance from
    # the snout is its body's centre of mass (from the snout) minus its local x
    for k, f in enumerate(fishes):
        g = fish_geometry(f.length_m, f.height_m, f.width_m, f.weight_kg, fin_joined=True)
        snout = g.bodies[0].com_from_snout_m - p["section_x"][p["section_body"] == 4 * k][0]
        tip = g.bodies[3].com_from_snout_m - p["section_x"][p["section_body"] == 4 * k + 3][-1]
        assert snout == pytest.approx(0.0, abs=1e-6)
        assert tip == pytest.approx(f.length_m, rel=1e-5)


def test_the_contact_search_cells_decide_speed_not_which_contacts_act():
    """Two fish dropped onto a belt, the second onto the first: with search cells of 0.1, 0.3 (the joined fish's own) and
    1 m every body ends where it ended with the others, to rounding (the cells change only the order in which the
    contact forces are summed), and each fish model brings its own cells."""
    assert PlantParams.model_validate({"fish_model": "joined4"}).numerics.search_cell_m == 0.3
    assert PlantParams.model_validate({"fish_model": "paper5"}).numerics.search_cell_m == 0.1
    ends = []
    for cell_m in (0.1, 0.3, 1.0):
        params = PlantParams.model_validate({"fish_model": "joined4", "numerics": {"search_cell_m": cell_m}})
        pair = [fish("f01", length_m=0.6, x_m=1.0), fish("f02", length_m=0.6, x_m=1.1, z_m=0.08, yaw_rad=0.3)]
        plant = Plant(straight_line(("c1", 0.0, 3.0, 0.0)), pair, params=params)
        for _ in range(100):
            plant.step({"c1": 0.4})
        ends.append(plant.state.pos.copy())
    assert ends[0].shape == (8, 3) and np.all(ends[0][:, 2] > 0.0)
    assert np.abs(ends[1] - ends[0]).max() < 1e-12 and np.abs(ends[2] - ends[0]).max() < 1e-12  # 1e-15 measured


def test_the_friction_table_holds_every_level_the_fish_take_and_cutting_it_changes_no_contact():
    """Without directional friction a fish's friction level never changes, so the table Exudyn gets stops at the
    highest level a body of the run's fish takes (mucus and a gradient along the fish move them): the coefficients
    are the full table's, and a pile of fish with mucus of three ages on a graded friction runs to the last bit as
    with the full table (the full table forced on a twin plant at every rebuild)."""
    from dataclasses import replace

    from plant.fish.extensions import FRICTION_LEVELS, body_friction_levels
    from plant.sim.model import MAT_FISH0, friction_pairings
    from plant.sim.plant import Plant

    full = np.array(friction_pairings(0.3, 0.2, 0.4))
    short = np.array(friction_pairings(0.3, 0.2, 0.4, (), 90))
    assert short.shape == (MAT_FISH0 + 90,) * 2 and np.array_equal(short, full[:MAT_FISH0 + 90, :MAT_FISH0 + 90])

    params = PlantParams.model_validate({"friction": {"belt_gradient": 0.4}, "numerics": {"step_s": 0.002},
                                         "extensions": {"mucus_friction": {"gain": 1.5, "time_constant_h": 10.0}}})
    line = straight_line(("c1", 0.0, 2.0, 0.0))
    fishes = [replace(fish(f"f{k}", x_m=0.5 + 0.05 * k, t_s=0.05 + 0.1 * k, z_m=0.02 + 0.09 * k),
                      hours_post_mortem=h) for k, h in enumerate((1.0, 12.0, 48.0))]
    cut, whole = Plant(line, fishes, params), Plant(line, fishes, params)
    whole._highest_level = None  # the full table at every rebuild
    taken = [int(body_friction_levels(int(lv), 0.4, 4).max()) for lv in cut._level]
    assert cut._highest_level == max(taken) and FRICTION_LEVELS[max(taken)] > 2.0  # the oldest fish's tail
    for _ in range(80):
        cut.step({"c1": 0.3})
        whole.step({"c1": 0.3})
    assert (cut.status == 1).all()
    assert np.array_equal(cut.state.pos, whole.state.pos) and np.array_equal(cut.state.vel, whole.state.vel)
