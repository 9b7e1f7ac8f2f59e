"""Laying out and assembling the Exudyn system of a line and its fish (what is in it: :mod:`plant.sim.model`).

A system is made in two parts.  Its **layout**, the line's items and each fish's nodes, bodies, spheres, loads and
joints in order, depends only on which fish are in it and the friction level each is laid out with.  The fish's
**state**, each body's position, rotation and velocity, gravity on or off and each joint's linearisation, is set
after it, and the system is assembled.  What the model takes from the layout alone (its solver, settings, sphere and
outline arrays, the fish's arrays) is made once the layout is complete (:func:`finish`).  A rebuild does all at once.
Served in real time, the plant lays out the next rebuilds' systems ahead, in the wall time the steps leave over
(:meth:`plant.sim.plant.Plant.build_ahead`), so that the rebuild, when it comes, only sets the state, assembles and
initialises the solver: the same values reach Exudyn either way, so the system and every step after it are the same
to the bit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from plant.sim.exudyn_module import exu  # the fast build, quiet; a missing system library in one line
from exudyn.itemInterface import (  # after exudyn_module: Exudyn loaded as the plant wants it
    LoadForceVector, MarkerBodyPosition, MarkerBodyRigid, NodeRigidBodyRotVecLG, ObjectGround, ObjectRigidBody)

from plant.contract.line import Line
from plant.fish.extensions import FRICTION_LEVELS, body_friction_levels
from plant.fish.fish_body import FISH_MODELS
from plant.sim.model import (BELT_MASS_KG, MAT_BELT, MAT_FISH0, MAT_GUIDE, MAT_SECTION0, PARK_SPACING_M,
                             TRIANGLE_STIFFNESS, FishArrays, FishModel, Member, PlantModel, PreparedFish, friction_pairings,
                             fish_arrays, park_top_z)
from plant.sim.params import PlantParams
from plant.sim.surfaces import LineSurfaces

_ROTATION_DIAGONAL = (np.array([3, 4, 5]), np.array([3, 4, 5]))
"""The rotational stiffnesses' places in a joint connector's 6 x 6 stiffness."""


@dataclass
class _FishItems:
    """What the fish added to the system so far, in order: their body nodes, contact spheres (body, position in it,
    radius) and outline cross-sections (body, offset along it, half length, radius)."""

    body_nodes: list[int] = field(default_factory=list)
    sphere_body: list[int] = field(default_factory=list)
    sphere_local: list[tuple] = field(default_factory=list)
    sphere_radius: list[float] = field(default_factory=list)
    outlines: list[np.ndarray] = field(default_factory=list)
    """Each fish's :attr:`PreparedFish.outline`, its body index made the system's."""

    def sections(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(body, offset along it, half length, radius) of every cross-section of the system."""
        rows = np.concatenate(self.outlines) if self.outlines else np.zeros((0, 4))
        return rows[:, 0].astype(np.int64), rows[:, 1].copy(), rows[:, 2].copy(), rows[:, 3].copy()


@dataclass
class _Finished:
    """What a system's model takes from its layout alone: its solver and settings, its spheres and outline
    cross-sections as arrays, its fish's arrays."""

    solver: exu.MainSolverExplicit
    settings: exu.SimulationSettings
    sphere_body: np.ndarray
    sphere_local: np.ndarray
    sphere_radius: np.ndarray
    sections: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    arrays: FishArrays


@dataclass
class Layout:
    """A system being laid out: the line and the fish added so far, without their state; not assembled."""

    system: exu.SystemContainer
    mbs: exu.MainSystem
    contact: exu.GeneralContact
    params: PlantParams
    line: Line
    belt_nodes: list[int]
    device_nodes: list[int]
    items: _FishItems = field(default_factory=_FishItems)
    fish: list[FishModel] = field(default_factory=list)
    planned: tuple[tuple[int, int], ...] = ()
    """Laid out ahead (:func:`lay_out_ahead`): the (fish index, friction level) of each fish it is to hold; those
    laid out so far (:attr:`keys`) are the first of them."""
    finished: _Finished | None = None
    """What follows from the layout alone, made once all its fish are in (:func:`finish`)."""

    @property
    def keys(self) -> tuple[tuple[int, int], ...]:
        """(fish index, friction level) of each fish laid out, in order."""
        return tuple((f.index, f.friction_level) for f in self.fish)


def member_keys(members: list[Member]) -> tuple[tuple[int, int], ...]:
    """The layout ``members`` need: (fish index, friction level) of each, in order."""
    return tuple((m.index, m.friction_level) for m in members)


def lay_out(surfaces: LineSurfaces, params: PlantParams, line: Line, highest_level: int | None = None) -> Layout:
    """A new system with the line in it (its ``surfaces``, worked out once per run by
    :func:`plant.sim.surfaces.line_surfaces`) and no fish yet.  ``highest_level``: the highest friction level a body
    of a fish of the run can take (None: any, as directional friction may)."""
    system = exu.SystemContainer()
    mbs = system.AddSystem()
    gc = mbs.AddGeneralContact()
    gc.verboseMode = 0
    gc.frictionProportionalZone = params.numerics.friction_regularization_mps
    wear = params.extensions.guide_wear
    section_factors = tuple(wear.sections(line.x_start_m, line.x_end_m)[1].tolist()) if wear.on else ()
    fish_levels = len(FRICTION_LEVELS) if highest_level is None or section_factors else highest_level + 1
    gc.SetFrictionPairings(friction_pairings(params.friction.fish_belt, params.friction.fish_guide,
                                             params.friction.fish_fish, section_factors, fish_levels))
    belt_nodes, device_nodes = _add_line(mbs, gc, surfaces, line, section_factors)
    return Layout(system, mbs, gc, params, line, belt_nodes, device_nodes)


def assemble(layout: Layout, members: list[Member], gravity: np.ndarray) -> PlantModel:
    """The laid-out system with its fish (the ``members``, in the layout's order) in their given states, assembled;
    the layout is used up."""
    if layout.keys != member_keys(members):
        raise ValueError(f"the system was laid out for fish {layout.keys}, not {member_keys(members)}")
    mbs, params, line, items = layout.mbs, layout.params, layout.line, layout.items
    for fm, mem in zip(layout.fish, members):
        _set_state(mbs, fm, mem, gravity)
    # contact search: a box over the line, the space above it and the parking grid below it
    lo = np.array([line.x_start_m - 0.6, -0.5 * line.guide_width_m - 0.15,
                   park_top_z(line) - PARK_SPACING_M[2] * 4 - 0.3])
    hi = np.array([line.x_end_m + params.retire_after_m + 1.0, 0.5 * line.guide_width_m + 0.15,
                   line.z_range_m[1] + 1.2])
    layout.contact.SetSearchTreeBox(lo, hi)
    layout.contact.SetSearchTreeCellSize([max(1, int(np.ceil(s_ / params.numerics.search_cell_m))) for s_ in hi - lo])
    mbs.Assemble()

    sd = mbs.systemData
    body_ltg = np.array([sd.GetNodeLTGODE2(n) for n in items.body_nodes], dtype=np.int64).reshape(-1, 6)
    # the reference coordinates as set (Exudyn keeps the doubles given): no read back
    body_ref = np.vstack([m.coords for m in members]).reshape(-1, 6) if members else np.zeros((0, 6))
    belt_ltg = np.array([sd.GetNodeLTGODE2(n) for n in layout.belt_nodes], dtype=np.int64)
    device_ltg = np.array([sd.GetNodeLTGODE2(n) for n in layout.device_nodes], dtype=np.int64).reshape(-1, 6)
    done = layout.finished or finish(layout)
    return PlantModel(layout.system, mbs, layout.contact, done.settings, done.solver, done.arrays, line, params,
                      layout.fish, body_ltg, body_ref, belt_ltg, done.sphere_body, done.sphere_local,
                      done.sphere_radius, *done.sections, (lo, hi), device_ltg)


def finish(layout: Layout) -> _Finished:
    """What the model of a fully laid-out system takes from its layout alone (made ahead if served, see
    :func:`lay_out_ahead`)."""
    items = layout.items
    layout.finished = _Finished(
        exu.MainSolverExplicit(), _solver_settings(layout.params.numerics), np.array(items.sphere_body, dtype=np.int64),
        np.array(items.sphere_local).reshape(-1, 3), np.array(items.sphere_radius), items.sections(),
        fish_arrays(layout.fish, FISH_MODELS[layout.params.fish_model]))
    return layout.finished


def build_model(surfaces: LineSurfaces, members: list[Member], params: PlantParams, gravity: np.ndarray,
                line: Line, highest_level: int | None = None, ahead: tuple[Layout, ...] = ()) -> PlantModel:
    """Lay out, set and assemble the line and the given fish in their given states: a rebuild, in one go or on a
    layout made ``ahead`` for these fish (the one planned for them, if any; the fish it lacks added now)."""
    keys = member_keys(members)
    layout = next((a for a in ahead if a.planned == keys), None) or lay_out(surfaces, params, line, highest_level)
    for mem in members[len(layout.fish):]:
        add_fish(layout, mem.index, mem.prepared, mem.friction_level)
    return assemble(layout, members, gravity)


@dataclass
class AheadCost:
    """What laying out ahead took (wall s, a moving mean): the line's items, a fish's, finishing a layout.  A piece
    is begun only if its cost fits in the time left, and every piece put off lowers its cost a little (a slow one is
    not believed forever)."""

    line_s: float = 1.0e-3
    fish_s: float = 3.0e-4
    finish_s: float = 5.0e-4

    def fits(self, piece_s: float, until_s: float) -> bool:
        return time.perf_counter() + piece_s <= until_s

    def took(self, name: str, since_s: float) -> None:
        setattr(self, name, 0.5 * getattr(self, name) + 0.5 * (time.perf_counter() - since_s))


def lay_out_ahead(layouts: list[Layout], plans: list[tuple[tuple[int, int], ...]], prepared: list[PreparedFish],
                  surfaces: LineSurfaces, params: PlantParams, line: Line, highest_level: int | None,
                  until_s: float, cost: AheadCost) -> list[Layout]:
    """Layouts for the ``plans`` (each the (fish index, friction level) of the fish a rebuild may hold, in order),
    laid out further in the plans' order, a piece at a time while its ``cost`` fits before the clock
    (``time.perf_counter``) reaches ``until_s``; those of ``layouts`` made for one of the plans are kept, the
    others let go."""
    kept = {layout.planned: layout for layout in layouts}
    out = []
    for planned in plans:
        if (layout := kept.get(planned)) is None and cost.fits(cost.line_s, until_s):
            t0 = time.perf_counter()
            layout = lay_out(surfaces, params, line, highest_level)
            layout.planned = planned
            cost.took("line_s", t0)
        if layout is None:
            cost.line_s *= 0.9
            continue
        out.append(layout)
        while len(layout.fish) < len(planned):
            if not cost.fits(cost.fish_s, until_s):
                cost.fish_s *= 0.9
                break
            t0 = time.perf_counter()
            k, level = planned[len(layout.fish)]
            add_fish(layout, k, prepared[k], level)
            cost.took("fish_s", t0)
        if len(layout.fish) == len(planned) and layout.finished is None:
            if cost.fits(cost.finish_s, until_s):
                t0 = time.perf_counter()
                finish(layout)
                cost.took("finish_s", t0)
            else:
                cost.finish_s *= 0.9
    return out


def _add_line(mbs, gc, surfaces: LineSurfaces, line: Line, section_factors: tuple[float, ...]) -> tuple[list, list]:
    """The line's surfaces into the system: guides, parts and bins static, then a body for each belt and each device
    (moved by the plant every step); returns the belts' and the devices' nodes."""
    ground = mbs.AddObject(ObjectGround())
    m_ground = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground))
    # guides (in sections of their own friction with guide wear), fixed parts and the gates' bins: static, added
    # before the moving belts as Exudyn requires
    statics = [(MAT_GUIDE, surfaces.guides)] if not section_factors else [
        (MAT_SECTION0 + k, tris) for k, tris in enumerate(surfaces.guide_sections)]
    for material, (pts, trigs) in [*statics, (MAT_GUIDE, surfaces.parts), (MAT_GUIDE, surfaces.bins)]:
        if trigs:
            gc.AddTrianglesRigidBodyBased(rigidBodyMarkerIndex=m_ground, contactStiffness=TRIANGLE_STIFFNESS,
                                          contactDamping=0.0, frictionMaterialIndex=material, pointList=pts,
                                          triangleList=trigs, staticTriangles=True)
    belt_nodes = []
    for c, (pts, trigs) in zip(line.conveyors, surfaces.belts):
        # an inclined belt's body is turned about y: its local x runs up (or down) the belt
        node = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[c.x_start_m, 0.0, c.z_top_m, 0.0,
                                                                       -np.radians(c.incline_deg), 0.0]))
        body = mbs.AddObject(ObjectRigidBody(mass=BELT_MASS_KG, inertia=[BELT_MASS_KG] * 3 + [0.0] * 3, nodeNumber=node))
        marker = mbs.AddMarker(MarkerBodyRigid(bodyNumber=body))
        gc.AddTrianglesRigidBodyBased(rigidBodyMarkerIndex=marker, contactStiffness=TRIANGLE_STIFFNESS, contactDamping=0.0,
                                      frictionMaterialIndex=MAT_BELT, pointList=pts, triangleList=trigs, staticTriangles=False)
        belt_nodes.append(node)
    device_nodes = []
    for shape in surfaces.devices:  # moved like the belts: put at their pose and given its rate every step
        node = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[*shape.origin_m, 0.0, 0.0, 0.0]))
        body = mbs.AddObject(ObjectRigidBody(mass=BELT_MASS_KG, inertia=[BELT_MASS_KG] * 3 + [0.0] * 3, nodeNumber=node))
        marker = mbs.AddMarker(MarkerBodyRigid(bodyNumber=body))
        gc.AddTrianglesRigidBodyBased(rigidBodyMarkerIndex=marker, contactStiffness=TRIANGLE_STIFFNESS, contactDamping=0.0,
                                      frictionMaterialIndex=MAT_BELT if shape.device.kind == "gate" else MAT_GUIDE,
                                      pointList=shape.points_m.tolist(),
                                      triangleList=shape.triangles.tolist(), staticTriangles=False)
        device_nodes.append(node)
    return belt_nodes, device_nodes


def add_fish(layout: Layout, index: int, prep: PreparedFish, friction_level: int) -> None:
    """One fish into the layout, without its state: its bodies with a gravity load each (set when assembled),
    contact spheres, outline and (with adhesion) a force load each, and its joints."""
    mbs, gc, items, params = layout.mbs, layout.contact, layout.items, layout.params
    num = params.numerics
    geo = prep.geometry
    first = len(items.body_nodes)
    # contact: one spring per sphere from the fish's mass per sphere (see NumericsParams);
    # the same for all its bodies, so a fast tail fin is stopped as firmly as the body
    m_share = prep.spec.weight_kg / prep.n_spheres
    k_c = m_share * num.contact_omega_rad_s**2
    d_c = 2.0 * num.contact_damping_ratio * np.sqrt(k_c * m_share)
    nodes, objects, loads, sticky = [], [], [], []
    first_sphere = len(items.sphere_body)
    materials = MAT_FISH0 + body_friction_levels(friction_level, params.friction.belt_gradient, len(geo.bodies))
    zeros = [0.0] * 6
    for i, (b, inertia) in enumerate(zip(geo.bodies, prep.inertias)):
        # a fish's items as plain dicts: Exudyn's item classes cost 3.5 us more an item (2 ms a rebuild of 8 fish)
        node = mbs.AddNode({"nodeType": "RigidBodyRotVecLG", "referenceCoordinates": zeros})
        obj = mbs.AddObject({"objectType": "RigidBody", "mass": b.mass_kg, "inertia": [*inertia, 0.0, 0.0, 0.0],
                             "nodeNumber": node})
        mass = mbs.AddMarker({"markerType": "BodyMass", "bodyNumber": obj})
        loads.append(mbs.AddLoad({"loadType": "MassProportional", "markerNumber": mass, "loadVector": zeros[:3]}))
        for (x, y, r) in b.spheres:
            marker = mbs.AddMarker({"markerType": "BodyRigid", "bodyNumber": obj, "localPosition": [x, y, 0.0]})
            gc.AddSphereWithMarker(marker, radius=r, contactStiffness=k_c, contactDamping=d_c,
                                   frictionMaterialIndex=int(materials[i]))
            items.sphere_body.append(first + i)
            items.sphere_local.append((x, y, 0.0))
            items.sphere_radius.append(r)
        if params.extensions.adhesion.on:
            com = mbs.AddMarker(MarkerBodyPosition(bodyNumber=obj, localPosition=[0.0, 0.0, 0.0]))
            sticky.append(mbs.AddLoad(LoadForceVector(markerNumber=com, loadVector=[0.0, 0.0, 0.0])))
        nodes.append(node)
        objects.append(obj)
        items.body_nodes.append(node)
    items.outlines.append(prep.outline + np.array([first, 0.0, 0.0, 0.0]))  # copied as a whole, not row by row
    connectors = []
    for j in range(len(geo.bodies) - 1):
        a, b = geo.bodies[j], geo.bodies[j + 1]
        xj = geo.joint_from_snout_m[j]
        m0, m1 = (mbs.AddMarker({"markerType": "BodyRigid", "bodyNumber": objects[j + e],
                                 "localPosition": [body.com_from_snout_m - xj, 0.0, 0.0]}) for e, body in ((0, a), (1, b)))
        stiffness, damping = prep.joint_springs[j]  # the rotational stiffness zero until the state is set
        connectors.append(mbs.AddObject({
            "objectType": "ConnectorRigidBodySpringDamper", "markerNumbers": [m0, m1], "stiffness": stiffness,
            "damping": damping, "offset": zeros, "useIntrinsicFormulation": True}))
    layout.fish.append(FishModel(index, prep, first, connectors, loads, first_sphere,
                                 len(items.sphere_body) - first_sphere, sticky, nodes, friction_level))


def _set_state(mbs, fm: FishModel, mem: Member, gravity: np.ndarray) -> None:
    """A laid-out fish's state: its bodies' coordinates and velocities, gravity (none while parked), its joints'
    linearisation (plant.sim.joints)."""
    for i, node in enumerate(fm.nodes):
        mbs.SetNodeParameter(node, "referenceCoordinates", mem.coords[i].tolist())
        mbs.SetNodeParameter(node, "initialVelocities", mem.velocities[i].tolist())
        if mem.gravity:
            mbs.SetLoadParameter(fm.gravity_loads[i], "loadVector", list(gravity))
    for j, conn in enumerate(fm.connectors):
        stiffness = fm.prepared.joint_springs[j][0].copy()
        stiffness[_ROTATION_DIAGONAL] = mem.joint_k[j]
        mbs.SetObjectParameter(conn, "stiffness", stiffness)
        mbs.SetObjectParameter(conn, "offset", [0.0] * 3 + list(mem.joint_offset[j]))


def _solver_settings(num) -> exu.SimulationSettings:
    """Explicit integration (VelocityVerlet) at ``num.step_s`` with no end (the plant extends it chunk by chunk),
    each body's mass matrix inverted alone, no files, ``num.threads``."""
    ss = exu.SimulationSettings()
    ss.timeIntegration.endTime = 1.0e6
    ss.timeIntegration.numberOfSteps = int(round(1.0e6 / num.step_s))
    ss.timeIntegration.solverType = exu.DynamicSolverType.VelocityVerlet
    ss.timeIntegration.explicit.computeEndOfStepAccelerations = False
    ss.timeIntegration.explicit.computeMassMatrixInversePerBody = True
    ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    ss.solution.file.write = False
    ss.timeIntegration.verboseMode = 0
    ss.parallel.numberOfThreads = num.threads
    return ss
