"""Stepping the plant from outside, one communication step at a time (the co-simulation interface).

>>> from plant.contract.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "photoeyes": [{"id": "pe1", "x_m": 1.5, "z_m": 0.015}]})
>>> plant = Plant(line, fish=[])
>>> out = plant.step({"c1": 0.3})
>>> round(plant.t_s, 3), out.photoeyes["pe1"], sorted(plant.input_ports())
(0.01, False, ['c1.speed'])
>>> plant.state.outputs is out, plant.state.t_s == plant.t_s
(True, True)

One step is a short, fixed pipeline (read it top to bottom):

1. admit and release the fish whose drop time has come (placed clear of the fish already there);
2. set the belt speeds (each belt body back in place, moving at its speed);
3. re-linearise the joints that are at or running into their limits; with the model's extensions
   (plant.fish.extensions) on, set each fish's friction by the direction it slips, and adhesion forces;
4. let Exudyn integrate to the end of the step;
5. read the state, work out the sensors, retire fish that have left the line, publish the state
   (:attr:`Plant.state`, a read-only :class:`plant.sim.state.PlantState`), check its health.

Only fish in play are in the Exudyn system (see :mod:`plant.sim.model`): when fish are about to be
dropped, or a quarter of those in the system have left the line, the system is rebuilt with the
state of every body carried over.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from plant.errors import SimulationError
from plant.fish.extensions import (FRICTION_LEVELS, adhesion_forces, body_friction_levels, direction_friction_levels,
                              friction_level, stiffening_limit_loss)
from plant.sim.health import check_health, floor_below
from plant.sim.joints import JointLaws, linearize, stack_laws
from plant.contract.line import Line
from plant.sim.model import (BELT_MASS_KG, MAT_FISH0, Member, PlantModel, build_model, park_positions, parked_member,
                         pose_coordinates, prepare_fish)
from plant.sim.params import PlantParams
from plant.fish.population import FishSpec
from plant.sim.rotations import lying_orientation, matrix_to_rotvec, rotvec_to_matrix
from plant.sim.sensors import belt_loads, photoeyes_blocked, sphere_centres, spine_point_local
from plant.sim import sleep as sleeping
from plant.sim.state import FishStatus, PlantOutputs, PlantState

WAITING, ON_LINE, LEFT = FishStatus.WAITING, FishStatus.ON_LINE, FishStatus.LEFT
ADMIT_AHEAD_S = 1.0
"""Fish due within this time are put into the system together (fewer rebuilds); they wait parked."""


@dataclass
class FishState:
    """Poses of all fish at the end of the last step (measured-data frame)."""

    t_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    yaw_rad: np.ndarray
    status: np.ndarray
    """:class:`FishStatus` (int8) of every fish: WAITING (not dropped yet), ON_LINE, or LEFT (gone past the
    end of the line)."""


@dataclass
class DropAdjustment:
    fish_id: str
    raised_by_m: float


class Plant:
    """The line and its fish in Exudyn, advanced by fixed communication steps."""

    def __init__(self, line: Line, fish: list[FishSpec], params: PlantParams | None = None,
                 comm_step_s: float = 0.01, joint_factors: list[tuple[float, float]] | None = None) -> None:
        self.line = line
        self.params = params or PlantParams()
        self.fish_specs = list(fish)
        self._fish_ids = [f.fish_id for f in self.fish_specs]
        self._fish_id_tuple = tuple(self._fish_ids)
        self._drop_t_s = np.array([f.drop_t_s for f in self.fish_specs], dtype=float)  # one comparison per step
        n_sub = comm_step_s / self.params.numerics.step_s
        if abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise ValueError(f"communication step {comm_step_s} s is not a whole multiple of the integration "
                             f"step {self.params.numerics.step_s} s")
        self.comm_step_s = comm_step_s
        self.conveyor_ids = [c.id for c in line.conveyors]
        self.photoeye_ids = [p.id for p in line.photoeyes]
        self._beams = np.array([[p.x_m, p.z_m] for p in line.photoeyes]).reshape(-1, 2)
        self._x_ends = np.array([c.x_end_m for c in line.conveyors])
        self._gravity = self.params.gravity_mps2 * np.array(
            [np.sin(np.radians(self.params.incline_deg)), 0.0, -np.cos(np.radians(self.params.incline_deg))])
        self._gravity.setflags(write=False)
        ext = self.params.extensions
        if joint_factors is None:
            joint_factors = [ext.rigor_mortis.joint_factors(f.hours_post_mortem) if ext.rigor_mortis.on else (1.0, 1.0)
                             for f in self.fish_specs]
            k0 = self.params.joints.stiffening
            if k0 > 0.0:  # every fish stiffer, at any age: added to rigor's stiffness, its range loss multiplied
                keep = 1.0 - stiffening_limit_loss(k0)
                joint_factors = [(s + k0, lim * keep) for s, lim in joint_factors]
        self.prepared = [prepare_fish(f, self.params, joint_factors[k]) for k, f in enumerate(self.fish_specs)]
        # each fish's friction multiplier on belts and guides: mucus (hours post mortem) x direction of slip
        self._mucus = np.array([ext.mucus_friction.factor(f.hours_post_mortem) for f in self.fish_specs])
        self._level = friction_level(self._mucus) if len(self.fish_specs) else np.zeros(0, dtype=np.int64)
        self._spine_refs = [tuple(spine_point_local(p.geometry, s) for s in (0.5, 0.2, 0.8)) for p in self.prepared]
        self._fish_mass_kg = np.array([sum(b.mass_kg for b in prep.geometry.bodies) for prep in self.prepared])
        self.status = np.full(len(self.fish_specs), WAITING, dtype=np.int8)
        self.drop_adjustments: list[DropAdjustment] = []
        self.rebuilds = 0
        self.timings_s = {"exudyn": 0.0, "rebuild": 0.0}
        """Wall time spent in Exudyn's solver and in rebuilding the system (for benchmarks)."""
        self._steps = 0
        self._t_model0 = 0.0
        # sleeping fish (plant.sim.sleep): carried with their belt outside the system
        n = len(self.fish_specs)
        self._sleep_enabled = self.params.numerics.sleep
        self._asleep = np.zeros(n, dtype=bool)
        self._to_wake: list[int] = []
        self._sleep_coords = np.zeros((n, 5, 6))
        self._sleep_rot = np.zeros((n, 5, 3, 3))
        self._sleep_k = np.zeros((n, 4, 3))
        self._sleep_offset = np.zeros((n, 4, 3))
        self._sleep_box = np.zeros((n, 2, 3))
        self._sleep_belt = np.zeros(n, dtype=np.int64)
        self._sleep_speed = np.zeros(n)
        self._ride_count = np.zeros(n, dtype=np.int64)
        self._sleep_load_n = np.zeros(len(line.conveyors))
        self._sleep_mass_kg = np.zeros(len(line.conveyors))
        self._x_starts = np.array([c.x_start_m for c in line.conveyors])
        self.fish_steps_asleep = 0
        """Fish x communication steps carried kinematically (for benchmarks)."""
        self.fish_steps_on_line = 0
        self._set_model(build_model(line, [], self.params, self._gravity), [])
        self._publish(PlantOutputs.at_rest(self.conveyor_ids, self.photoeye_ids))

    # ---- ports -------------------------------------------------------------------------------
    def input_ports(self) -> list[str]:
        return [f"{c}.speed" for c in self.conveyor_ids]

    def output_ports(self) -> list[str]:
        out = []
        for c in self.conveyor_ids:
            out += [f"{c}.speed", f"{c}.load_force", f"{c}.load_mass"]
        return out + [f"{p}.blocked" for p in self.photoeye_ids]

    @property
    def t_s(self) -> float:
        return self._steps * self.comm_step_s

    @property
    def state(self) -> PlantState:
        """The plant after the last step (read-only; at rest before the first step): what readers
        outside the plant use (the energy watch, re-simulation), never the plant's private fields."""
        return self._state

    # ---- the step ----------------------------------------------------------------------------
    def step(self, belt_speeds_mps: dict[str, float] | np.ndarray) -> PlantOutputs:
        """Advance one communication step with the given belt surface speeds."""
        speeds = self._speeds_array(belt_speeds_mps)
        self._admit_and_release(self.t_s + 1e-9)
        if self._sleep_enabled:
            self._carry_sleepers(speeds)
        self._set_belts(speeds)
        self._relinearize_joints()
        self._update_friction(speeds)
        self._apply_adhesion()
        self._solver.it.endTime = (self._steps + 1) * self.comm_step_s - self._t_model0
        t0 = time.perf_counter()
        self._solver.SolveSteps(self.model.mbs, self.model.settings)
        self.timings_s["exudyn"] += time.perf_counter() - t0
        self._steps += 1
        self._read_state()
        outputs = self._sensors(speeds)
        self._retire_fish()
        if self._sleep_enabled:
            self.fish_steps_on_line += int(np.count_nonzero(self.status == ON_LINE))
            if self._steps % 10 == 0:
                self._put_to_sleep(speeds)
        self._publish(outputs)
        self._check_health()
        return outputs

    # ---- the system: which fish are in it ----------------------------------------------------
    def _set_model(self, model: PlantModel, members: list[Member]) -> None:
        from plant.sim.model import exu  # imported there once, with a missing system library reported as such
        self.model = model
        self._slot_of = {m.index: i for i, m in enumerate(members)}
        self._member = model.member_index
        self._fish_of_body = np.repeat(self._member, 5)
        self._body_mass = np.array([b.mass_kg for k in self._member for b in self.prepared[k].geometry.bodies],
                                   dtype=float)
        self._body_inertia = np.array([np.asarray(i, dtype=float) for k in self._member
                                       for i in self.prepared[k].inertias], dtype=float).reshape(-1, 3)
        self._laws = stack_laws([m.prepared.laws for m in members])
        self._k_now = np.vstack([m.joint_k for m in members]) if members else np.zeros((0, 3))
        self._offset_now = np.vstack([m.joint_offset for m in members]) if members else np.zeros((0, 3))
        self._joint_bodies = np.array([(5 * i + j, 5 * i + j + 1) for i in range(len(members)) for j in range(4)],
                                      dtype=np.int64).reshape(-1, 2)
        self._pose_bodies = np.array([[5 * i + r[0] for r in self._spine_refs[m.index]] for i, m in enumerate(members)],
                                     dtype=np.int64).reshape(-1, 3)
        self._pose_local = np.array([[r[1] for r in self._spine_refs[m.index]] for m in members]).reshape(-1, 3, 3)
        self._solver = exu.MainSolverExplicit()
        ss = model.settings
        ss.timeIntegration.endTime = 1.0e6  # extended chunk by chunk
        ss.timeIntegration.numberOfSteps = int(round(1.0e6 / self.params.numerics.step_s))
        self._solver.InitializeSolver(model.mbs, ss)
        self._t_model0 = self.t_s
        self._adhesion_force = None
        self._read_state()

    def _rebuild(self, t: float) -> None:
        """A new system with the fish on the line (state carried over) and those due soon (parked)."""
        members = []
        for slot, k in enumerate(self._member):
            if self.status[k] == ON_LINE and not self._asleep[k]:
                b = slice(5 * slot, 5 * slot + 5)
                coords = np.hstack([self._pos[b], matrix_to_rotvec(self._rot[b])])
                vel = np.hstack([self._vel[b], self._omega_local[b]])
                j = slice(4 * slot, 4 * slot + 4)
                members.append(Member(int(k), self.prepared[k], coords, vel, True, self._k_now[j].copy(),
                                      self._offset_now[j].copy(), int(self._level[k])))
        for k in self._to_wake:  # back into the system as it was carried: riding at its belt's speed
            vel = np.zeros((5, 6))
            vel[:, 0] = self._sleep_speed[k]
            members.append(Member(int(k), self.prepared[k], self._sleep_coords[k].copy(), vel, True,
                                  self._sleep_k[k].copy(), self._sleep_offset[k].copy(), int(self._level[k])))
        self._to_wake = []
        due = [int(k) for k in np.flatnonzero((self.status == WAITING) & (self._drop_t_s <= t + ADMIT_AHEAD_S))]
        parks = park_positions(self.line, len(due))
        members += [parked_member(int(k), self.prepared[k], parks[i], int(self._level[k])) for i, k in enumerate(due)]
        t0 = time.perf_counter()
        self._set_model(build_model(self.line, members, self.params, self._gravity), members)
        self.timings_s["rebuild"] += time.perf_counter() - t0
        self.rebuilds += 1

    def _admit_and_release(self, t: float) -> None:
        due = [int(k) for k in np.flatnonzero((self.status == WAITING) & (self._drop_t_s <= t))]
        if not due:
            return
        woke = self._wake_near_drops(due) if self._sleep_enabled else False
        if woke or any(k not in self._slot_of for k in due):
            self._rebuild(t)
        for k in due:
            self._release(k)
        self._read_state()

    # ---- 1. drops ----------------------------------------------------------------------------
    def _release(self, k: int) -> None:
        spec = self.fish_specs[k]
        slot = self._slot_of[k]
        fm = self.model.fish[slot]
        rot = lying_orientation(spec.drop_yaw_rad, spec.side)
        mid = np.array([spec.drop_x_m, spec.drop_y_m, 0.0])
        sph = self.model.sphere_body
        mine = (sph >= fm.first_body) & (sph < fm.first_body + 5)
        local_body = sph[mine] - fm.first_body
        # sphere centres of the fish placed with its mid point at z = 0
        centres = (fm.prepared.body_offsets_m[local_body] + self.model.sphere_local[mine]) @ rot.T + mid
        radii = self.model.sphere_radius[mine]
        surface = self.line.z_top_at(spec.drop_x_m)
        z_mid = surface + spec.drop_z_m - float(np.min(centres[:, 2] - radii))
        # clear of fish already on the line below it: lowest sphere above their highest, plus the drop height
        on_line = (self.status[self._fish_of_body] == ON_LINE)[sph]
        if np.any(on_line):
            oc = sphere_centres(self._pos, self._rot, sph[on_line], self.model.sphere_local[on_line])
            orad = self.model.sphere_radius[on_line]
            d_xy = np.linalg.norm(centres[:, None, :2] - oc[None, :, :2], axis=2)
            near = d_xy < (radii[:, None] + orad[None, :] + 0.01)
            if np.any(near):
                top = np.max(np.where(near, oc[None, :, 2] + orad[None, :], -np.inf), axis=1)
                need = float(np.max(top + spec.drop_z_m - (z_mid + centres[:, 2] - radii)))
                if need > 0:
                    z_mid += need
                    self.drop_adjustments.append(DropAdjustment(spec.fish_id, need))
        mid[2] = z_mid
        self._place(slot, mid, rot, list(self._gravity))
        self.status[k] = ON_LINE
        self._read_state()

    # ---- 2. belts ----------------------------------------------------------------------------
    def _speeds_array(self, belt_speeds_mps: dict[str, float] | np.ndarray) -> np.ndarray:
        if isinstance(belt_speeds_mps, dict):
            missing = [c for c in self.conveyor_ids if c not in belt_speeds_mps]
            if missing:
                raise KeyError(f"no speed given for conveyor(s) {', '.join(missing)}")
            speeds = np.array([float(belt_speeds_mps[c]) for c in self.conveyor_ids])
        else:
            speeds = np.asarray(belt_speeds_mps, dtype=float).reshape(len(self.conveyor_ids))
        if not np.all(np.isfinite(speeds)):
            raise SimulationError(f"belt speed is not a number: {dict(zip(self.conveyor_ids, speeds))}", self.t_s)
        return speeds

    def _set_belts(self, speeds: np.ndarray) -> None:
        """Each belt body back at its place, shifted back half a step of travel, moving at its speed."""
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        ltg = self.model.belt_ltg
        q[ltg] = 0.0
        v[ltg] = 0.0
        q[ltg[:, 0]] = -0.5 * speeds * self.comm_step_s
        v[ltg[:, 0]] = speeds
        sd.SetODE2Coordinates(q)
        sd.SetODE2Coordinates_t(v)

    # ---- 3. joints ---------------------------------------------------------------------------
    def _relinearize_joints(self) -> None:
        if len(self._joint_bodies) == 0:
            return
        a, b = self._joint_bodies[:, 0], self._joint_bodies[:, 1]
        rel = np.einsum("nji,njk->nik", self._rot[a], self._rot[b])
        theta = matrix_to_rotvec(rel)
        # relative angular velocity in the frame of body a (node velocities are body-frame)
        w_b_in_a = np.einsum("nij,nj->ni", rel, self._omega_local[b])
        theta_next = theta + (w_b_in_a - self._omega_local[a]) * self.comm_step_s
        # joints well inside their limits (most of them) keep the soft spring: evaluate the law only
        # for those near a limit now or by the end of the step
        soft_until = self._laws.limit_rad * (1.0 - self._laws.transition)
        near = np.any((np.abs(theta) > soft_until) | (np.abs(theta_next) > soft_until), axis=1)
        near &= np.repeat(self.status[self._member] == ON_LINE, 4)
        k_new = self._laws.k_soft.copy()
        off_new = np.zeros_like(self._offset_now)
        if np.any(near):
            sub = JointLaws(self._laws.limit_rad[near], self._laws.k_soft[near], self._laws.k_limit[near],
                            self._laws.transition, self._laws.damping[near])
            k_new[near], off_new[near] = linearize(sub, theta[near], theta_next[near])
        changed = (np.any(np.abs(k_new - self._k_now) > 0.02 * self._k_now, axis=1)
                   | np.any(np.abs(off_new - self._offset_now) > 0.005, axis=1))
        if not np.any(changed):
            return
        mbs = self.model.mbs
        for j in np.flatnonzero(changed):
            conn = self.model.fish[j // 4].connectors[j % 4]
            stiffness = np.array(mbs.GetObjectParameter(conn, "stiffness"))
            stiffness[3:, 3:] = np.diag(k_new[j])
            mbs.SetObjectParameter(conn, "stiffness", stiffness)
            mbs.SetObjectParameter(conn, "offset", [0.0, 0.0, 0.0, *off_new[j]])
        self._k_now[changed] = k_new[changed]
        self._offset_now[changed] = off_new[changed]

    def _update_friction(self, speeds: np.ndarray) -> None:
        """Direction-dependent friction: each fish's friction material from the way it slips now."""
        direction = self.params.extensions.direction_friction
        if not direction.on or len(self._member) == 0:
            return
        on = np.flatnonzero(self.status[self._member] == ON_LINE)
        if not len(on):
            return
        pts = self._pos[self._pose_bodies[on]] + np.einsum("mkij,mkj->mki", self._rot[self._pose_bodies[on]],
                                                           self._pose_local[on])
        k = self._member[on]
        new = direction_friction_levels(pts[:, :, :2], self._vel[self._pose_bodies[on, 0], :2],
                                        speeds[self._conveyor_index(pts[:, 0, 0])], self._mucus[k], self._level[k],
                                        direction, 0.5 * self.params.numerics.friction_regularization_mps)
        gc = self.model.contact
        gradient = self.params.friction.belt_gradient
        for i in np.flatnonzero(new != self._level[k]):
            fm = self.model.fish[on[i]]
            materials = MAT_FISH0 + body_friction_levels(int(new[i]), gradient)
            for sphere in range(fm.first_sphere, fm.first_sphere + fm.n_spheres):
                body = int(self.model.sphere_body[sphere]) - fm.first_body
                gc.SetSphereMarkerBased(sphere, frictionMaterialIndex=int(materials[body]))
        self._level[k] = new

    def _apply_adhesion(self) -> None:
        """Touching fish attract: the adhesion forces of the state now, set as loads where they changed."""
        adhesion = self.params.extensions.adhesion
        if not adhesion.on or len(self._member) == 0:
            return
        m = self.model
        body_on = self.status[self._fish_of_body] == ON_LINE
        sel = np.flatnonzero(body_on[m.sphere_body])
        centres = sphere_centres(self._pos, self._rot, m.sphere_body[sel], m.sphere_local[sel])
        force = adhesion_forces(centres, m.sphere_radius[sel], m.sphere_body[sel], self._fish_of_body,
                                len(self._pos), adhesion)
        prev = self._adhesion_force
        if prev is None or prev.shape != force.shape:
            prev = np.zeros_like(force)
        for b in np.flatnonzero(np.any(force != prev, axis=1)):
            fm = m.fish[b // 5]
            m.mbs.SetLoadParameter(fm.adhesion_loads[b % 5], "loadVector", list(force[b]))
        self._adhesion_force = force

    def _conveyor_index(self, x_m: np.ndarray) -> np.ndarray:
        """Index of the conveyor under each x (in a gap: the downstream one)."""
        return np.clip(np.searchsorted(self._x_ends, x_m, side="right"), 0, len(self._x_ends) - 1)

    # ---- 5. state, sensors, retirement, health ------------------------------------------------
    def _read_state(self) -> None:
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        coords = q[self.model.body_ltg] + self.model.body_ref
        vel = v[self.model.body_ltg]
        self._coords = coords
        self._pos = coords[:, :3]
        self._rot = rotvec_to_matrix(coords[:, 3:])
        self._vel = vel[:, :3]
        self._omega_local = vel[:, 3:]
        self._belt_vel_end = v[self.model.belt_ltg[:, :3]] if len(self.model.belt_ltg) else np.zeros((0, 3))

    def _sensors(self, speeds: np.ndarray) -> PlantOutputs:
        load, mass = belt_loads(self._belt_vel_end, speeds, BELT_MASS_KG, self.comm_step_s, self.params.gravity_mps2)
        if self._sleep_enabled:  # fish carried outside the system still weigh on their belt
            load, mass = load + self._sleep_load_n, mass + self._sleep_mass_kg
        blocked = self._beams_blocked()
        return PlantOutputs(
            t_s=self.t_s,
            belt_speed_mps=dict(zip(self.conveyor_ids, map(float, speeds))),
            belt_load_force_n=dict(zip(self.conveyor_ids, map(float, load))),
            belt_load_mass_kg=dict(zip(self.conveyor_ids, map(float, mass))),
            photoeyes=dict(zip(self.photoeye_ids, map(bool, blocked))))

    def _beams_blocked(self) -> np.ndarray:
        """Photo-eyes against the outline cross-sections of the fish bodies near a beam."""
        m = self.model
        if len(self._beams) == 0 or len(m.section_body) == 0:
            return np.zeros(len(self._beams), dtype=bool)
        body_on = self.status[self._fish_of_body] == ON_LINE
        near = body_on & (np.min(np.abs(self._pos[:, 0][:, None] - self._beams[None, :, 0]), axis=1) < 0.5)
        sel = near[m.section_body]
        if not np.any(sel):
            return np.zeros(len(self._beams), dtype=bool)
        b = m.section_body[sel]
        rot = self._rot[b]
        centres = self._pos[b] + rot[:, :, 0] * m.section_x[sel][:, None]
        return photoeyes_blocked(centres, rot[:, :, 1], m.section_half_len[sel], m.section_radius[sel],
                                 self._beams, 0.5 * self.line.guide_width_m)

    def _retire_fish(self) -> None:
        """Fish past the end of the line (or fallen off its end) are parked; the next rebuild drops them.

        Checked every tenth step: a fish takes far longer than that to clear the end of the line."""
        if self._steps % 10:
            return
        on = self.status[self._member] == ON_LINE
        if not np.any(on):
            return
        pos = self._pos.reshape(-1, 5, 3)
        x_gone = self.line.x_end_m + self.params.retire_after_m
        z_floor = min(c.z_top_m for c in self.line.conveyors) - 0.5
        past = np.all(pos[:, :, 0] > x_gone, axis=1)
        fell_off_end = np.all(pos[:, :, 0] > self.line.x_end_m, axis=1) & np.all(pos[:, :, 2] < z_floor, axis=1)
        # one that left slowly drops beside the end drum, some of it not past the end: gone once far below
        fell_off_end |= (np.max(pos[:, :, 0], axis=1) > self.line.x_end_m - 0.1) & np.all(pos[:, :, 2] < z_floor - 0.5,
                                                                                        axis=1)
        slots = np.flatnonzero(on & (past | fell_off_end))
        if not len(slots):
            return
        parks = park_positions(self.line, len(self.model.fish))
        for slot in slots:
            self._park(int(slot), parks[slot])
            self.status[self._member[slot]] = LEFT
        gone = int(np.sum(self.status[self._member] == LEFT))
        if gone >= max(2, len(self._member) // 4):
            self._rebuild(self.t_s)
        else:
            self._read_state()

    def _park(self, slot: int, where: np.ndarray) -> None:
        self._place(slot, where, np.eye(3), [0.0, 0.0, 0.0])

    def _place(self, slot: int, mid: np.ndarray, rot: np.ndarray, gravity: list[float]) -> None:
        """Put the fish of ``slot`` at rest at ``mid`` with orientation ``rot``, under ``gravity``
        (none while parked)."""
        idx, values = pose_coordinates(self.model, slot, mid, rot)
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        q[idx] = values
        v[idx] = 0.0
        sd.SetODE2Coordinates(q)
        sd.SetODE2Coordinates_t(v)
        for load in self.model.fish[slot].gravity_loads:
            self.model.mbs.SetLoadParameter(load, "loadVector", gravity)

    def _publish(self, outputs: PlantOutputs) -> None:
        """The state after this step, as readers outside the plant see it (:attr:`state`).  The arrays
        are shared, not copied: every one of them is made anew when it changes (by :meth:`_read_state`,
        :meth:`_set_model`, :meth:`_apply_adhesion`), except the status, which is copied."""
        self._state = PlantState(
            t_s=self.t_s, fish_ids=self._fish_id_tuple, status=self.status.copy(), member=self._member,
            fish_of_body=self._fish_of_body, pos=self._pos, rot=self._rot, vel=self._vel,
            omega_local=self._omega_local, body_mass_kg=self._body_mass, body_inertia=self._body_inertia,
            fish_mass_kg=self._fish_mass_kg, gravity_mps2=self._gravity, adhesion_force_n=self._adhesion_force,
            outputs=outputs, asleep=self._asleep.copy() if self._sleep_enabled else None)

    def _check_health(self) -> None:
        s = self._state
        body_on = s.on_line_bodies()
        if not np.any(body_on):
            return
        check_health(s.pos[body_on], s.vel[body_on], s.fish_of_body[body_on], s.fish_ids, self.line, s.t_s)

    # ---- sleeping fish (plant.sim.sleep) -----------------------------------------------------------
    def _member_boxes(self) -> np.ndarray:
        """(n_slots, 2, 3) boxes around the contact spheres of each fish in the system."""
        m = self.model
        centres = sphere_centres(self._pos, self._rot, m.sphere_body, m.sphere_local)
        return sleeping.fish_boxes(centres, m.sphere_radius, m.sphere_body // 5, len(self._member))

    def _mu_belt(self, ks: np.ndarray) -> np.ndarray:
        # the least gripping body decides whether friction can hold the fish
        return (self.params.friction.fish_belt * FRICTION_LEVELS[self._level[ks]]
                * (1.0 - abs(self.params.friction.belt_gradient)))

    def _wake(self, ks) -> None:
        for k in ks:
            self._asleep[k] = False
            self._ride_count[k] = 0
            self._to_wake.append(int(k))

    def _wake_near_drops(self, due: list[int]) -> bool:
        """Wake the sleeping fish within reach of where a fish is about to be dropped."""
        ks = np.flatnonzero(self._asleep)
        if not len(ks):
            return False
        drop_x = np.array([self.fish_specs[k].drop_x_m for k in due])
        reach = np.array([self.fish_specs[k].length_m for k in due]) + sleeping.CLEAR_M
        box = self._sleep_box[ks]
        near = np.any((box[:, 1, 0][:, None] > drop_x - reach) & (box[:, 0, 0][:, None] < drop_x + reach), axis=1)
        self._wake(ks[near])
        return bool(np.any(near))

    def _carry_sleepers(self, speeds: np.ndarray) -> None:
        """Wake the sleeping fish whose motion could change in this step (then rebuild); move the others
        with their belts over the step, and put their weight (and the force to accelerate them) on it."""
        self._sleep_load_n[:] = 0.0
        self._sleep_mass_kg[:] = 0.0
        ks = np.flatnonzero(self._asleep)
        if not len(ks):
            return
        dt = self.comm_step_s
        belt = self._sleep_belt[ks]
        v = speeds[belt]
        wake = sleeping.too_fast_a_change(v, self._sleep_speed[ks], dt, self._mu_belt(ks), self.params.gravity_mps2)
        wake |= sleeping.near_end(self._sleep_box[ks], self._x_ends[belt], self._beams[:, 0], v * dt)
        on = np.flatnonzero(self.status[self._member] == ON_LINE)
        if len(on):
            reach = sleeping.WAKE_CLEAR_M + dt * (float(np.abs(self._vel).max(initial=0.0)) + np.abs(v))
            gap = sleeping.box_gap(self._sleep_box[ks], self._member_boxes()[on])
            wake |= np.any(gap < reach[:, None], axis=1)
        if np.any(wake):
            self._wake(ks[wake])
            self._rebuild(self.t_s)
        rest, v = ks[~wake], v[~wake]
        if not len(rest):
            return
        m = self._fish_mass_kg[rest]
        np.add.at(self._sleep_load_n, self._sleep_belt[rest], m * (v - self._sleep_speed[rest]) / dt)
        np.add.at(self._sleep_mass_kg, self._sleep_belt[rest], m)
        self._sleep_coords[rest, :, 0] += (v * dt)[:, None]
        self._sleep_box[rest, :, 0] += (v * dt)[:, None]
        self._sleep_speed[rest] = v
        self.fish_steps_asleep += len(rest)

    def _put_to_sleep(self, speeds: np.ndarray) -> None:
        """Fish that have ridden with their belt for a while, alone and clear of ends, photo-eyes and
        guides, leave the system (a rebuild) and are carried from now on."""
        slots = np.flatnonzero(self.status[self._member] == ON_LINE)
        if not len(slots):
            return
        pos = self._pos.reshape(-1, 5, 3)[slots]
        belt_speed = speeds[self._conveyor_index(pos[:, :, 0])]
        ride = sleeping.riding(self._vel.reshape(-1, 5, 3)[slots], self._omega_local.reshape(-1, 5, 3)[slots],
                               belt_speed)
        ks = self._member[slots]
        self._ride_count[ks] = np.where(ride, self._ride_count[ks] + 1, 0)
        cand = np.flatnonzero(ride & (self._ride_count[ks] >= sleeping.SLEEP_AFTER_CHECKS))
        if not len(cand):
            return
        boxes = self._member_boxes()
        belt = sleeping.on_one_belt_clear(boxes[slots[cand]], self._x_starts, self._x_ends, self._beams[:, 0],
                                          0.5 * self.line.guide_width_m)
        others = np.concatenate([boxes[slots], self._sleep_box[self._asleep]])
        gap = sleeping.box_gap(boxes[slots[cand]], others)
        gap[np.arange(len(cand)), cand] = np.inf  # not from itself
        chosen = np.flatnonzero((belt >= 0) & np.all(gap >= sleeping.CLEAR_M, axis=1))
        if not len(chosen):
            return
        for i in chosen:
            slot, k = int(slots[cand[i]]), int(ks[cand[i]])
            b, j = slice(5 * slot, 5 * slot + 5), slice(4 * slot, 4 * slot + 4)
            self._sleep_coords[k] = self._coords[b]
            self._sleep_rot[k] = self._rot[b]
            self._sleep_k[k], self._sleep_offset[k] = self._k_now[j], self._offset_now[j]
            self._sleep_box[k] = boxes[slot]
            self._sleep_belt[k] = belt[i]
            self._sleep_speed[k] = speeds[belt[i]]
            self._asleep[k] = True
        self._rebuild(self.t_s)

    def floor_below(self, x_m: np.ndarray) -> np.ndarray:
        """Lowest belt top within 0.1 m of each x: where a fish can lie, drape or hang over a drum."""
        return floor_below(self.line, x_m)

    # ---- state for recording -----------------------------------------------------------------
    def fish_state(self) -> FishState:
        """Mid-length point and heading of every fish on the line (NaN for the others).

        The heading is that of the chord from the spine point at 80 % of the length to the one at
        20 %: what an overhead camera sees as the fish's direction, robust to a wagging head or tail.
        """
        n = len(self.fish_specs)
        x, y, z, yaw = (np.full(n, np.nan) for _ in range(4))
        slots = np.flatnonzero(self.status[self._member] == ON_LINE)
        if len(slots):
            b = self._pose_bodies[slots]  # (m, 3): bodies holding the 50 %, 20 %, 80 % points
            pts = self._pos[b] + np.einsum("mkij,mkj->mki", self._rot[b], self._pose_local[slots])
            chord = pts[:, 1] - pts[:, 2]
            k = self._member[slots]
            x[k], y[k], z[k] = pts[:, 0, 0], pts[:, 0, 1], pts[:, 0, 2]
            yaw[k] = np.arctan2(chord[:, 1], chord[:, 0])
        for k in np.flatnonzero(self._asleep):
            pts = np.array([self._sleep_coords[k, b, :3] + self._sleep_rot[k, b] @ local
                            for b, local in self._spine_refs[k]])
            chord = pts[1] - pts[2]
            x[k], y[k], z[k] = pts[0]
            yaw[k] = np.arctan2(chord[1], chord[0])
        return FishState(self.t_s, x, y, z, yaw, self.status.copy())

    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (5 n_fish, 3), rotation matrices (5 n_fish, 3, 3)) of every fish's bodies, in the
        run's fish order; NaN for fish not in the system (waiting or gone)."""
        n = 5 * len(self.fish_specs)
        pos = np.full((n, 3), np.nan)
        rot = np.full((n, 3, 3), np.nan)
        body_index = (5 * self._fish_of_body + np.tile(np.arange(5), len(self._member))) if len(self._member) else []
        pos[body_index] = self._pos
        rot[body_index] = self._rot
        for k in np.flatnonzero(self._asleep):
            pos[5 * k:5 * k + 5] = self._sleep_coords[k, :, :3]
            rot[5 * k:5 * k + 5] = self._sleep_rot[k]
        return pos, rot

    def body_velocities(self) -> np.ndarray:
        n = 5 * len(self.fish_specs)
        vel = np.full((n, 3), np.nan)
        if len(self._member):
            vel[5 * self._fish_of_body + np.tile(np.arange(5), len(self._member))] = self._vel
        for k in np.flatnonzero(self._asleep):
            vel[5 * k:5 * k + 5] = [self._sleep_speed[k], 0.0, 0.0]
        return vel
