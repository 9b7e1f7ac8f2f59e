"""What the Exudyn system of a line and its fish is made of (laid out and assembled by :mod:`plant.sim.system`).

What is in it:

- **Side guides and the infeed end plate**: static triangles (GeneralContact), normals inwards.
- **Belts**: one heavy free body per conveyor carrying its top-surface triangles (with the drum
  radius as a short rounded lip at each end).  GeneralContact takes friction from the velocity
  of the body that carries the triangles, so before every communication step the plant puts
  each belt body back in place and gives it the belt speed: the surface moves, the geometry
  stays (to within half a step of travel).  The body's momentum change over the step is the
  force the fish put on the belt.
- **Fish**: five rigid bodies each (``plant.fish.fish_body``), rotation-vector nodes for the explicit
  Lie-group integrator, gravity as a mass-proportional load per body (switched off while a fish
  waits for its drop or after it has left the line), contact spheres, and four rigid-body
  spring-dampers (stiff in translation, ``plant.sim.joints`` laws in rotation).
- Only the fish in play are in the system: every contact sphere costs time at every force
  evaluation whether it touches anything or not, so a fish waiting for its drop or gone past the
  outfeed would cost as much as one on the line.  The plant rebuilds the system when fish are
  about to be dropped or enough have left (:class:`Member` carries each body's state over); a fish
  admitted shortly before its drop waits in a parking grid below the line with gravity off.

The numbers that decide stability are documented in ``plant.sim.params.NumericsParams``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from plant.sim.exudyn_module import exu  # the fast build, quiet; a missing system library in one line

from plant.fish.extensions import FRICTION_LEVELS
from plant.fish.fish_body import FISH_MODELS, FishGeometry, fish_geometry
from plant.sim.joints import JointLaws, joint_laws, stack_laws
from plant.contract.devices import BIN_DEPTH_M, device_shapes
from plant.contract.line import Line
from plant.sim.params import PlantParams
from plant.fish.population import FishSpec
from plant.sim.rotations import matrix_to_rotvec


MAT_BELT, MAT_GUIDE, MAT_FISH0 = 0, 1, 2
"""Friction materials: belts, guides, then one per fish friction level (plant.fish.extensions.FRICTION_LEVELS), then
with guide wear one per guide section (:data:`MAT_SECTION0` on)."""
MAT_SECTION0 = MAT_FISH0 + len(FRICTION_LEVELS)
BELT_MASS_KG = 1.0e5
"""Mass of a belt body: the fish cannot move it measurably within one step (1 N for 10 ms -> 1e-7 m/s)."""
TRIANGLE_STIFFNESS = 1.0e8
"""Stiffness of belt and guide triangles; in series with a sphere's much softer spring, so the sphere's rules."""
PARK_SPACING_M = (0.8, 0.25, 0.2)


@dataclass(frozen=True)
class PreparedFish:
    """What a fish is, worked out once per run: bodies, simulated inertias, joint laws."""

    spec: FishSpec
    geometry: FishGeometry
    inertias: tuple[np.ndarray, ...]
    laws: JointLaws
    body_offsets_m: np.ndarray
    """(5, 3) body centre of mass relative to the mid-length point, in the fish frame."""
    n_spheres: int
    outline: np.ndarray
    """(n_sections, 4) the outline's cross-sections, head first: (body index in the fish, offset along the body, half
    length, radius); the photo-eyes read them (plant.sim.sensors), every rebuild copies them."""
    joint_springs: np.ndarray
    """(n_joints, 2, 6, 6) each joint's stiffness with its rotational block zero (the state's linearisation goes
    there at each rebuild) and its damping, as the joint's connector takes them: made once, copied at each rebuild."""
    spine_refs: tuple[tuple[int, np.ndarray], ...]
    """(body, position in it) of the tracked spine points at 0.5, 0.2 and 0.8 of the length from the snout."""
    tip_refs: tuple[tuple[int, np.ndarray], ...]
    """(body, position in it) of the snout and the tail's tip."""


@dataclass
class Member:
    """A fish to put into the system, with its bodies' state (positions, rotation vectors, velocities,
    body-frame angular velocities) and its joints' current linearisation."""

    index: int
    """The fish's index in the run's list of fish."""
    prepared: PreparedFish
    coords: np.ndarray
    """(5, 6): position and rotation vector of each body."""
    velocities: np.ndarray
    """(5, 6): velocity and angular velocity (body frame) of each body."""
    gravity: bool
    joint_k: np.ndarray
    """(4, 3) current rotational stiffness of each joint (see plant.sim.joints.linearize)."""
    joint_offset: np.ndarray
    friction_level: int = 80
    """Index into FRICTION_LEVELS of the fish's current friction multiplier (80: x 1.0)."""


@dataclass
class FishModel:
    """Where one fish lives in the Exudyn system."""

    index: int
    prepared: PreparedFish
    first_body: int
    """Index of its head in the model's body arrays (bodies are consecutive, head to tail fin)."""
    connectors: list[int]
    gravity_loads: list[int]
    first_sphere: int
    n_spheres: int
    adhesion_loads: list[int] = field(default_factory=list)
    """A force load at each body's centre of mass, when adhesion is on."""
    nodes: list[int] = field(default_factory=list)
    """Its bodies' nodes, head first (their state is set when the system is assembled)."""
    friction_level: int = 80
    """The friction level its spheres' material was laid out with."""

    @property
    def spec(self) -> FishSpec:
        return self.prepared.spec


@dataclass(frozen=True)
class FishArrays:
    """The fish of a system, body by body and joint by joint in its order: fixed until the next rebuild, so made
    with its layout (ahead, if served) and published as they are (read-only)."""

    member_index: np.ndarray
    """The run's fish index of each fish in the system."""
    fish_of_body: np.ndarray
    body_mass_kg: np.ndarray
    body_inertia: np.ndarray
    """(n_bodies, 3) principal inertias as simulated."""
    laws: JointLaws
    """Every joint's law, stacked (plant.sim.joints)."""
    joint_bodies: np.ndarray
    """(n_joints, 2) the two bodies of each joint."""
    pose_bodies: np.ndarray
    """(n_fish, 3) the body of each tracked spine point (:attr:`PreparedFish.spine_refs`); pose_local: where in it."""
    pose_local: np.ndarray
    tip_bodies: np.ndarray
    """(n_fish, 2) the body of the snout and of the tail's tip; tip_local: where in it."""
    tip_local: np.ndarray


def fish_arrays(fish: list[FishModel], bodies_per_fish: int) -> FishArrays:
    """The arrays of the ``fish`` of a system, in its order."""
    nb, prepared = bodies_per_fish, [f.prepared for f in fish]
    member = np.array([f.index for f in fish], dtype=np.int64)
    laws = stack_laws([p.laws for p in prepared])
    laws.table  # worked out here (cached properties, with the zone), not in the first step after the rebuild
    arrays = FishArrays(
        member, np.repeat(member, nb),
        np.array([b.mass_kg for p in prepared for b in p.geometry.bodies], dtype=float),
        np.array([np.asarray(i, dtype=float) for p in prepared for i in p.inertias], dtype=float).reshape(-1, 3),
        laws, np.array([(nb * i + j, nb * i + j + 1) for i in range(len(fish)) for j in range(nb - 1)],
                       dtype=np.int64).reshape(-1, 2),
        np.array([[nb * i + r[0] for r in p.spine_refs] for i, p in enumerate(prepared)], dtype=np.int64).reshape(-1, 3),
        np.array([[r[1] for r in p.spine_refs] for p in prepared]).reshape(-1, 3, 3),
        np.array([[nb * i + r[0] for r in p.tip_refs] for i, p in enumerate(prepared)], dtype=np.int64).reshape(-1, 2),
        np.array([[r[1] for r in p.tip_refs] for p in prepared]).reshape(-1, 2, 3))
    for published in (arrays.member_index, arrays.fish_of_body, arrays.body_mass_kg, arrays.body_inertia,
                      arrays.pose_bodies, arrays.pose_local):  # published as they are, no view a step
        published.setflags(write=False)
    return arrays


@dataclass
class PlantModel:
    """The assembled Exudyn system and the index arrays the stepping code needs."""

    system: exu.SystemContainer
    mbs: exu.MainSystem
    contact: exu.GeneralContact
    settings: exu.SimulationSettings
    solver: exu.MainSolverExplicit
    """Made with the system, initialised by the plant when it takes the system."""
    arrays: FishArrays
    line: Line
    params: PlantParams
    fish: list[FishModel]
    body_ltg: np.ndarray
    """(n_bodies, 6) indices of each body's coordinates in the system's ODE2 vectors."""
    body_ref: np.ndarray
    """(n_bodies, 6) reference coordinates (position, rotation vector) of each body node."""
    belt_ltg: np.ndarray
    sphere_body: np.ndarray
    """(n_spheres,) body index of each contact sphere."""
    sphere_local: np.ndarray
    """(n_spheres, 3) sphere centre in its body's frame."""
    sphere_radius: np.ndarray
    section_body: np.ndarray
    """(n_sections,) body index of each outline cross-section (for sensors, see plant.sim.sensors)."""
    section_x: np.ndarray
    """(n_sections,) local x of each cross-section."""
    section_half_len: np.ndarray
    section_radius: np.ndarray
    search_box: tuple[np.ndarray, np.ndarray] = field(default=(np.zeros(3), np.zeros(3)))
    device_ltg: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), dtype=np.int64))
    """(n_devices, 6) indices of each device body's coordinates (origin at its home pose, rotation vector)."""

    @property
    def bodies_per_fish(self) -> int:
        """Every fish in the system has as many bodies (its slot s holds bodies nb s .. nb s + nb - 1)."""
        return FISH_MODELS[self.params.fish_model]


def _shaped_inertia(body, enabled: bool, share: float = 0.5) -> np.ndarray:
    """Principal inertias, raised where the body's spheres would make its rotation too stiff.

    A thin body (the tail fin) carries its contact spheres far from its own axes compared with
    its tiny inertia, so rolling on them is the fastest motion in the model.  Raising the
    inertia to what the sphere layout implies slows that motion down without changing mass,
    centre of mass or how the fish moves as a whole.  ``share``: the part of the sphere-implied inertia about
    the lateral and dorsal axes it is raised to (the joined fish takes all of it: its tail with the fin is
    the longest thin body).
    """
    inertia = np.array(body.inertia_kgm2, dtype=float)
    if not enabled:
        return inertia
    sp = np.array(body.spheres)
    m = body.mass_kg
    inertia[0] = max(inertia[0], m * float(np.mean(sp[:, 1] ** 2)))
    inertia[1] = max(inertia[1], share * m * float(np.mean(sp[:, 0] ** 2)))
    inertia[2] = max(inertia[2], share * m * float(np.mean(sp[:, 0] ** 2 + sp[:, 1] ** 2)))
    return inertia


def park_top_z(line: Line) -> float:
    """Height of the parking grid's top layer: 0.6 m below the lowest belt, and 0.3 m below the bottom of any gate's
    bin (a parked fish has no gravity; one overlapping a wall would be shot off by its contact)."""
    bins = [s.hinge_z_m - BIN_DEPTH_M - 0.3 for s in device_shapes(line) if s.device.kind == "gate"]
    return min([line.z_range_m[0] - 0.6, *bins])


def park_positions(line: Line, n: int) -> np.ndarray:
    """Waiting places for n fish (slot k at the k-th): a grid below the line (at most four layers deep: few fish wait).
    Every fish in the system has its own (a fish parked on another would be shot off by their contact)."""
    dx, dy, dz = PARK_SPACING_M
    nx = max(1, int((line.x_end_m - line.x_start_m) // dx))
    ny = max(1, int(line.guide_width_m // dy) + 1)
    z0 = park_top_z(line)
    out = np.zeros((n, 3))
    for k in range(n):
        ix, rest = k % nx, k // nx
        iy, iz = rest % ny, rest // ny
        out[k] = (line.x_start_m + 0.4 + ix * dx, (iy - (ny - 1) / 2) * dy, z0 - iz * dz)
    return out


@functools.lru_cache(maxsize=16)
def friction_pairings(fish_belt: float, fish_guide: float, fish_fish: float,
                      guide_sections: tuple[float, ...] = (), fish_levels: int = len(FRICTION_LEVELS)
                      ) -> list[list[float]]:
    """Coulomb coefficients between materials (fish levels scale their friction on belts and guides) as Exudyn takes
    them fastest: a list (it converts in half the time of an array), made once for all the rebuilds of a run.
    Shared: never changed.  ``guide_sections``: each guide section's factor on the fish-guide friction (guide wear),
    one material each from :data:`MAT_SECTION0`.  ``fish_levels``: only the first that many levels get a material
    (the levels above the highest any fish of the run can take; all of them with guide sections): Exudyn converts
    the whole table at every rebuild, 0.9 ms for all 281 levels, a rebuild's most costly single call."""
    if guide_sections and fish_levels != len(FRICTION_LEVELS):
        raise ValueError("guide sections take their materials after every fish level")
    levels = FRICTION_LEVELS[:fish_levels]
    mu = np.zeros((MAT_FISH0 + fish_levels + len(guide_sections),) * 2)
    fish = slice(MAT_FISH0, MAT_FISH0 + fish_levels)
    mu[MAT_BELT, fish] = mu[fish, MAT_BELT] = fish_belt * levels
    mu[MAT_GUIDE, fish] = mu[fish, MAT_GUIDE] = fish_guide * levels
    for k, factor in enumerate(guide_sections):
        mu[MAT_SECTION0 + k, fish] = mu[fish, MAT_SECTION0 + k] = fish_guide * factor * levels
    mu[fish, fish] = fish_fish
    return mu.tolist()


def prepare_fish(spec: FishSpec, params: PlantParams, joint_factor: tuple[float, float] = (1.0, 1.0)) -> PreparedFish:
    """Cut a fish into bodies and work out its inertias and joint laws (once per run)."""
    num = params.numerics
    joined = params.fish_model == "joined4"
    geo = fish_geometry(spec.length_m, spec.height_m, spec.width_m, spec.weight_kg,
                        sphere_spacing=num.sphere_spacing, min_body_fraction=num.min_body_mass_fraction,
                        fin_joined=joined)
    inertias = tuple(_shaped_inertia(b, num.inertia_shaping, 1.0 if joined else 0.5) for b in geo.bodies)
    laws = joint_laws(geo, params.joints, num, params.gravity_mps2, list(inertias), *joint_factor)
    offsets = np.array([[geo.mid_from_snout_m - b.com_from_snout_m, 0.0, 0.0] for b in geo.bodies])
    outline = np.array([(i, x, max(half_h - half_w, 0.0), half_w) for i, b in enumerate(geo.bodies)
                        for (x, half_h, half_w) in b.outline]).reshape(-1, 4)
    springs = []
    for j, (a, b) in enumerate(zip(geo.bodies[:-1], geo.bodies[1:])):
        # the joint's translation held by a stiff spring from the two bodies' reduced mass
        m_red = a.mass_kg * b.mass_kg / (a.mass_kg + b.mass_kg)
        k_t = m_red * num.joint_translation_omega_rad_s**2
        d_t = 2.0 * params.joints.damping_ratio * np.sqrt(k_t * m_red)
        springs.append((np.diag([k_t] * 3 + [0.0] * 3), np.diag([d_t] * 3 + list(laws.damping[j]))))
    return PreparedFish(spec, geo, inertias, laws, offsets, sum(len(b.spheres) for b in geo.bodies), outline,
                        np.array(springs).reshape(-1, 2, 6, 6),
                        tuple(geo.spine_point(s) for s in (0.5, 0.2, 0.8)),
                        tuple(geo.spine_point(s) for s in (0.0, 1.0)))


def parked_member(index: int, prepared: PreparedFish, park_m: np.ndarray, friction_level: int) -> Member:
    """A fish straight and at rest at a parking place, gravity off, joints at their soft stiffness."""
    n = len(prepared.geometry.bodies)
    coords = np.zeros((n, 6))
    coords[:, :3] = park_m[None, :] + prepared.body_offsets_m
    return Member(index, prepared, coords, np.zeros((n, 6)), False, prepared.laws.k_soft.copy(), np.zeros((n - 1, 3)),
                  friction_level)


def pose_coordinates(model: PlantModel, slot: int, mid_m: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ODE2 indices and values that put the fish in ``slot`` of the model straight at ``mid_m`` with ``rotation``."""
    fm = model.fish[slot]
    idx = slice(fm.first_body, fm.first_body + len(fm.prepared.geometry.bodies))
    pos = mid_m[None, :] + fm.prepared.body_offsets_m @ rotation.T
    rv = matrix_to_rotvec(rotation[None])[0]
    values = np.hstack([pos, np.repeat(rv[None, :], len(pos), axis=0)]) - model.body_ref[idx]
    return model.body_ltg[idx].ravel(), values.ravel()


def drop_height(centres: np.ndarray, radii: np.ndarray, surface_z: np.ndarray, drop_z_m: float,
                others: np.ndarray, others_radii: np.ndarray) -> tuple[float, float]:
    """(z of a dropped fish's mid point, how much higher than asked that is) for a fish whose sphere ``centres``
    (n, 3) are placed with its mid point at z = 0: its lowest sphere ``drop_z_m`` above the belt top under each
    sphere (``surface_z``), and clear of the fish already on the line below it (their spheres ``others`` (m, 3)):
    its lowest sphere above their highest, plus the drop height."""
    z_mid = float(np.max(surface_z + drop_z_m - (centres[:, 2] - radii)))
    if not len(others):
        return z_mid, 0.0
    d_xy = np.linalg.norm(centres[:, None, :2] - others[None, :, :2], axis=2)
    near = d_xy < (radii[:, None] + others_radii[None, :] + 0.01)
    if not np.any(near):
        return z_mid, 0.0
    top = np.max(np.where(near, others[None, :, 2] + others_radii[None, :], -np.inf), axis=1)
    need = float(np.max(top + drop_z_m - (z_mid + centres[:, 2] - radii)))
    return (z_mid + need, need) if need > 0 else (z_mid, 0.0)
