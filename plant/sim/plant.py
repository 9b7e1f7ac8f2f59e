"""Stepping the plant from outside, one communication step at a time (the co-simulation interface).

>>> from plant.contract.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "photoeyes": [{"id": "pe1", "x_m": 1.5, "z_m": 0.015}]})
>>> plant = Plant(line, fish=[])
>>> out = plant.step({"c1": 0.3})
>>> round(plant.state.t_s, 3), out.photoeyes["pe1"], plant.state.outputs is out
(0.01, False, True)

The plant has one output: after each step it publishes its state (:attr:`Plant.state`, a read-only
:class:`plant.sim.state.PlantState`, of which the step's return value is the sensor readings).  That is all
that code outside the plant reads of it (``tests/test_architecture.py`` checks fishfmu/); its inputs and
outputs are named by its ports (:mod:`plant.sim.ports`).  A run served in real time may also hand it the wall time
its steps leave over (:meth:`Plant.build_ahead`), which changes nothing it computes.

One step is a short, fixed pipeline (read it top to bottom):

1. admit and release the fish whose drop time has come (placed clear of the fish already there);
2. set the belt speeds (each belt body back in place, moving at its speed) and move the devices (each device
   body at its pose, moving at its actuator's rate: plant.sim.devices);
3. re-linearise the joints that are at or running into their limits; with the model's extensions
   (plant.fish.extensions) on, set each fish's friction by the direction it slips, and adhesion forces;
4. let Exudyn integrate to the end of the step;
5. read the state, work out the sensors, retire fish that have left the line or been taken off it by a device,
   publish the state, check its health.

Only fish in play are in the Exudyn system (:mod:`plant.sim.model`, :mod:`plant.sim.system`): when fish are about
to be dropped, or a quarter of those in it have left the line, it is rebuilt with every body's state carried over.
"""

from __future__ import annotations

import time

import numpy as np

from plant.contract.devices import step_for_devices
from plant.contract.line import Line
from plant.fish.extensions import (adhesion_forces, body_friction_levels, direction_friction_levels, friction_level,
                                   highest_body_level, stiffening_limit_loss)
from plant.fish.fish_body import FISH_MODELS
from plant.fish.population import FishSpec
from plant.sim.health import all_clear_on_line, check_health
from plant.sim.kernels import relinearized, rotation_matrices
from plant.sim.model import (MAT_FISH0, Member, PlantModel, drop_height, exu, park_positions, parked_member,
                             pose_coordinates, prepare_fish)
from plant.sim.params import PlantParams
from plant.sim.ports import PlantPorts
from plant.sim.rotations import lying_orientation, matrix_to_rotvec
from plant.sim.belts import Belts
from plant.sim.camera import Cameras, TopView, fish_seen_from_above
from plant.sim.devices import DeviceActuators
from plant.sim.equipment import Equipment, Seen, Step
from plant.sim.sensors import PhotoEyes, sphere_centres
from plant.sim.roster import ADMIT_AHEAD_S, FishRoster
from plant.sim.state import FishStatus, PlantOutputs, PlantState
from plant.sim.surfaces import line_surfaces
from plant.sim.system import AheadCost, build_model, lay_out_ahead

ON_LINE = FishStatus.ON_LINE


def equipment_of(line: Line, gravity_mps2: float, comm_step_s: float, seed: int) -> dict[str, Equipment]:
    """Every kind of the line's equipment (:mod:`plant.sim.equipment`), by the ports' ``of``, in the order the step
    runs them (belts before devices: a gate's surface runs at the speed of the belt before it)."""
    return {"conveyor": Belts.of(line, gravity_mps2), "photoeye": PhotoEyes.of(line, comm_step_s),
            "camera": Cameras.of(line, seed), "device": DeviceActuators.of(line)}


class Plant:
    """The line and its fish in Exudyn, advanced by fixed communication steps: :meth:`step` in, :attr:`state`
    out.  ``status``, ``t_s``, ``conveyor_ids`` and ``model`` are there for tests and scripts that look inside;
    fishfmu reads none of them."""

    def __init__(self, line: Line, fish: list[FishSpec], params: PlantParams | None = None,
                 comm_step_s: float = 0.01, joint_factors: list[tuple[float, float]] | None = None,
                 seed: int = 0) -> None:
        self._line = line
        self._params = params or PlantParams()
        if "step_s" not in self._params.numerics.model_fields_set:  # as a scenario does: shorter where a device needs it
            step_s = step_for_devices(line, comm_step_s, self._params.numerics.step_s)
            if step_s != self._params.numerics.step_s:
                self._params = self._params.model_copy(deep=True)
                self._params.numerics.step_s = step_s
        self._fish_specs = list(fish)
        self._fish_ids = tuple(f.fish_id for f in self._fish_specs)
        twice = sorted({i for i in self._fish_ids if self._fish_ids.count(i) > 1})
        if twice:  # a fish's id names its track, its passages and its place in the KPIs: two would be read as one
            raise ValueError(f"fish id '{twice[0]}' is given to {self._fish_ids.count(twice[0])} fish; each fish needs "
                             f"its own")
        self._roster = FishRoster.of(self._fish_specs)  # which fish waits, is in the system, on the line, gone
        n_sub = comm_step_s / self._params.numerics.step_s
        if abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise ValueError(f"communication step {comm_step_s} s is not a whole multiple of the integration "
                             f"step {self._params.numerics.step_s} s")
        self._comm_step_s = comm_step_s
        self._ports = PlantPorts.of(line)
        self.conveyor_ids = list(self._ports.conveyor_ids)
        self._x_ends = np.array([c.x_end_m for c in line.conveyors])
        self._surfaces = line_surfaces(line, self._params.guide_height_m, self._params.extensions.guide_wear)
        # belts, photo-eyes, cameras, devices: each kind run alike in the step (plant.sim.equipment)
        self._equipment = equipment_of(line, self._params.gravity_mps2, comm_step_s, seed)
        self._belts, self._devices = self._equipment["conveyor"], self._equipment["device"]
        tilt = np.radians(self._params.incline_deg)  # > 0: rising downstream (as a belt's), pulling fish back upstream
        self._gravity = self._params.gravity_mps2 * np.array([-np.sin(tilt), 0.0, -np.cos(tilt)])
        self._gravity.setflags(write=False)
        ext = self._params.extensions
        if joint_factors is None:
            joint_factors = [ext.rigor_mortis.joint_factors(f.hours_post_mortem) if ext.rigor_mortis.on else (1.0, 1.0)
                             for f in self._fish_specs]
            k0 = self._params.joints.stiffening
            if k0 > 0.0:  # every fish stiffer, at any age: added to rigor's stiffness, its range loss multiplied
                keep = 1.0 - stiffening_limit_loss(k0)
                joint_factors = [(s + k0, lim * keep) for s, lim in joint_factors]
        self._prepared = [prepare_fish(f, self._params, joint_factors[k]) for k, f in enumerate(self._fish_specs)]
        # each fish's friction multiplier on belts and guides: mucus (hours post mortem) x direction of slip
        self._mucus = np.array([ext.mucus_friction.factor(f.hours_post_mortem) for f in self._fish_specs])
        self._level = friction_level(self._mucus) if len(self._fish_specs) else np.zeros(0, dtype=np.int64)
        self._fish_mass_kg = np.array([sum(b.mass_kg for b in prep.geometry.bodies) for prep in self._prepared])
        self._fish_mass_kg.setflags(write=False)
        self._geometry = tuple(p.geometry for p in self._prepared)
        self._timings_s = {"exudyn": 0.0, "rebuild": 0.0, "rebuild_longest": 0.0}
        self._steps, self._t_model0, self._ahead_cost = 0, 0.0, AheadCost()
        self._retired_rebuild_due = False  # a retirement's rebuild: made before the next step, from this state
        # without directional friction a fish's level never changes: the friction table needs none above these
        self._highest_level = None if ext.direction_friction.on else highest_body_level(
            self._level, self._params.friction.belt_gradient, FISH_MODELS[self._params.fish_model])
        self._set_model(build_model(self._surfaces, [], self._params, self._gravity, line, self._highest_level), [])
        self._publish(PlantOutputs.at_rest(self._ports))

    @property
    def status(self) -> np.ndarray:
        """(n_fish,) every fish's :class:`~plant.sim.state.FishStatus` now (the roster's, written in place)."""
        return self._roster.status

    @property
    def t_s(self) -> float:
        return self._steps * self._comm_step_s

    @property
    def state(self) -> PlantState:
        """The plant after the last step (read-only; at rest before the first step): all that code outside
        the plant reads of it, never its other fields."""
        return self._state

    # ---- the step ----------------------------------------------------------------------------
    def step(self, belt_speeds_mps: dict[str, float] | np.ndarray,
             device_commands: dict[str, bool] | None = None) -> PlantOutputs:
        """Advance one communication step with the given belt surface speeds and device commands (by device id;
        a device not named, or all with None, is commanded home)."""
        self._rebuild_for_retired()
        speeds = self._belts.speeds(belt_speeds_mps, self.t_s)
        self._admit_and_release(self.t_s + 1e-9)  # may rebuild the system: the step's model is the one after it
        step = Step((self._steps + 1) * self._comm_step_s, self._comm_step_s, self.model, speeds,
                    self._devices.commands(device_commands))
        self._set_equipment(step)
        self._relinearize_joints()
        self._update_friction(speeds)
        self._apply_adhesion()
        self._solver.it.endTime = step.t_end_s - self._t_model0
        t0 = time.perf_counter()
        self._solver.SolveSteps(self.model.mbs, self.model.settings)
        self._timings_s["exudyn"] += time.perf_counter() - t0
        self._steps += 1
        self._read_state()
        outputs = self._sensors(step)
        self._retire_fish()
        self._publish(outputs)
        self._check_health()
        return outputs

    # ---- the system: which fish are in it ----------------------------------------------------
    def build_ahead(self, budget_s: float) -> None:
        """Within ``budget_s`` of wall time, lay out the systems of the next rebuilds as far as they can be foreseen
        (and let go of the one last replaced): a rebuild then only sets the state and assembles.  For a run served in
        real time, in the time its steps leave over; the run steps the same to the bit with or without it.  A rebuild
        the last step's retirements or the next step's admission need is made here at once, whatever the budget: it
        has to be made before that step in any case, and the state it carries is already the one that step starts
        from."""
        until_s, self._replaced = time.perf_counter() + budget_s, None
        self._rebuild_for_retired()
        if (due := self._roster.due(t := self.t_s + 1e-9)) and self._roster.must_admit(due):
            self._rebuild(t)  # the next step's admission rebuilds (as step() asks): now, in the time left over
        rear_x_m = self._pos[:, 0].reshape(-1, self.model.bodies_per_fish).min(axis=1)
        plans = [tuple((k, int(self._level[k])) for k in fish)
                 for fish in self._roster.next_rebuilds(self._steps, self._comm_step_s, rear_x_m)]
        self._ahead = lay_out_ahead(self._ahead, plans, self._prepared, self._surfaces, self._params, self._line,
                                    self._highest_level, until_s, self._ahead_cost)

    def _set_model(self, model: PlantModel, members: list[Member]) -> None:
        # the system replaced and the layouts made ahead for it: let go of in build_ahead's time, if served
        self._replaced = (getattr(self, "model", None), getattr(self, "_solver", None), getattr(self, "_ahead", None))
        self._ahead = []  # the next rebuilds' systems laid out ahead (build_ahead): none yet for this one
        self.model = model
        a = model.arrays
        self._roster.seated(a.member_index)
        self._member, self._fish_of_body, self._laws = a.member_index, a.fish_of_body, a.laws
        self._body_mass, self._body_inertia, self._joint_bodies = a.body_mass_kg, a.body_inertia, a.joint_bodies
        self._pose_bodies, self._pose_local, self._tip_bodies, self._tip_local = (a.pose_bodies, a.pose_local,
                                                                                  a.tip_bodies, a.tip_local)
        self._k_now = np.vstack([m.joint_k for m in members]) if members else np.zeros((0, 3))
        self._offset_now = np.vstack([m.joint_offset for m in members]) if members else np.zeros((0, 3))
        self._solver = model.solver
        self._solver.InitializeSolver(model.mbs, model.settings)
        self._t_model0 = self.t_s
        self._adhesion_force, self._joint_stiffness = None, {}  # connector -> its 6x6 stiffness, read once
        self._read_state()

    def _rebuild(self, t: float) -> None:
        """A new system with the fish on the line (state carried over) and those due soon (parked)."""
        nb = self.model.bodies_per_fish
        on = self._roster.on_line_slots(nb)
        coords, vel = np.zeros((len(on), 6)), np.hstack([self._vel, self._omega_local])
        coords[on] = np.hstack([self._pos[on], matrix_to_rotvec(self._rot[on])])  # row by row: as fish by fish
        members = [Member(int(k), self._prepared[k], coords[nb * s:nb * (s + 1)], vel[nb * s:nb * (s + 1)], True,
                          self._k_now[(j := slice((nb - 1) * s, (nb - 1) * (s + 1)))].copy(),
                          self._offset_now[j].copy(), int(self._level[k]))
                   for s, k in enumerate(self._member) if self.status[k] == ON_LINE]
        due = self._roster.due(t, ADMIT_AHEAD_S)
        parks = park_positions(self._line, len(members) + len(due))  # each slot its own place, as _retire_fish parks
        members += [parked_member(int(k), self._prepared[k], parks[len(members) + i], int(self._level[k]))
                    for i, k in enumerate(due)]
        t0 = time.perf_counter()
        self._set_model(build_model(self._surfaces, members, self._params, self._gravity, self._line,
                                    self._highest_level, tuple(self._ahead)), members)
        self._timings_s["rebuild"] += (took_s := time.perf_counter() - t0)
        self._timings_s["rebuild_longest"] = max(self._timings_s["rebuild_longest"], took_s)

    def _admit_and_release(self, t: float) -> None:
        due = self._roster.due(t)
        if not due:
            return
        if self._roster.must_admit(due):
            self._rebuild(t)
        for k in due:
            self._release(k)
        self._read_state()

    # ---- 1. drops ----------------------------------------------------------------------------
    def _release(self, k: int) -> None:
        spec = self._fish_specs[k]
        slot = self._roster.slot_of[k]
        fm = self.model.fish[slot]
        rot = lying_orientation(spec.drop_yaw_rad, spec.side)
        mid = np.array([spec.drop_x_m, spec.drop_y_m, 0.0])
        sph = self.model.sphere_body
        mine = (sph >= fm.first_body) & (sph < fm.first_body + self.model.bodies_per_fish)
        local_body = sph[mine] - fm.first_body
        # sphere centres of the fish placed with its mid point at z = 0
        centres = (fm.prepared.body_offsets_m[local_body] + self.model.sphere_local[mine]) @ rot.T + mid
        radii = self.model.sphere_radius[mine]
        surface = np.array([self._line.z_top_at(float(x)) for x in centres[:, 0]])  # under each sphere: inclines
        on_line = self._roster.on_line_slots(self.model.bodies_per_fish)[sph]
        others = sphere_centres(self._pos, self._rot, sph[on_line], self.model.sphere_local[on_line])
        z_mid, raised_by = drop_height(centres, radii, surface, spec.drop_z_m, others,
                                       self.model.sphere_radius[on_line])
        mid[2] = z_mid
        self._place(slot, mid, rot, list(self._gravity))
        self._roster.released(k, raised_by)
        self._read_state()

    # ---- 2. belts and devices ---------------------------------------------------------------
    def _set_equipment(self, step: Step) -> None:
        """What the equipment does before the solve: each belt body back at its place moving at its speed, each
        device body at its pose moving at its actuator's rate (plant.sim.belts, plant.sim.devices)."""
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()  # read again: a script may have set the system's state between steps
        v = sd.GetODE2Coordinates_t()
        for equipment in self._equipment.values():
            equipment.before_solve(step, q, v)
        sd.SetODE2Coordinates(q.tolist())  # Exudyn takes a list of floats faster than an array (the same doubles)
        sd.SetODE2Coordinates_t(v.tolist())

    # ---- 3. joints ---------------------------------------------------------------------------
    def _relinearize_joints(self) -> None:
        on = self._roster.on_line_slots(joints_per_fish := self.model.bodies_per_fish - 1)
        changed, k_new, off_new = relinearized(self._laws, self._rot, self._body_vel, self._joint_bodies, on,
                                               self._comm_step_s, self._k_now, self._offset_now)
        moved = np.flatnonzero(changed)
        if not len(moved):  # no spring to rewrite
            return
        mbs = self.model.mbs
        new_k = (k_new[moved] != self._k_now[moved]).any(axis=1)
        new_offset = (off_new[moved] != self._offset_now[moved]).any(axis=1)
        for i, j in enumerate(moved):
            conn = self.model.fish[j // joints_per_fish].connectors[j % joints_per_fish]
            if new_k[i]:  # only what moved is written; the 6x6 matrix read once, only its rotations' block moves
                if (stiffness := self._joint_stiffness.get(conn)) is None:
                    stiffness = self._joint_stiffness[conn] = np.array(mbs.GetObjectParameter(conn, "stiffness"))
                stiffness[3:, 3:] = np.diag(k_new[j])
                mbs.SetObjectParameter(conn, "stiffness", stiffness)
            if new_offset[i]:
                mbs.SetObjectParameter(conn, "offset", [0.0, 0.0, 0.0, *off_new[j]])
        self._k_now[moved], self._offset_now[moved] = k_new[moved], off_new[moved]

    def _update_friction(self, speeds: np.ndarray) -> None:
        """Direction-dependent friction: each fish's friction material from the way it slips now."""
        direction = self._params.extensions.direction_friction
        if not direction.on or len(self._member) == 0:
            return
        on = np.flatnonzero(self._roster.on_line_slots())
        if not len(on):
            return
        pts = self._pos[self._pose_bodies[on]] + np.einsum("mkij,mkj->mki", self._rot[self._pose_bodies[on]],
                                                           self._pose_local[on])
        k = self._member[on]
        new = direction_friction_levels(pts[:, :, :2], self._vel[self._pose_bodies[on, 0], :2],
                                        speeds[self._conveyor_index(pts[:, 0, 0])], self._mucus[k], self._level[k],
                                        direction, 0.5 * self._params.numerics.friction_regularization_mps)
        gc = self.model.contact
        gradient = self._params.friction.belt_gradient
        for i in np.flatnonzero(new != self._level[k]):
            fm = self.model.fish[on[i]]
            materials = MAT_FISH0 + body_friction_levels(int(new[i]), gradient, self.model.bodies_per_fish)
            for sphere in range(fm.first_sphere, fm.first_sphere + fm.n_spheres):
                body = int(self.model.sphere_body[sphere]) - fm.first_body
                gc.SetSphereMarkerBased(sphere, frictionMaterialIndex=int(materials[body]))
        self._level[k] = new

    def _apply_adhesion(self) -> None:
        """Touching fish attract: the adhesion forces of the state now, set as loads where they changed."""
        adhesion = self._params.extensions.adhesion
        if not adhesion.on or len(self._member) == 0:
            return
        m = self.model
        body_on = self._roster.on_line_slots(m.bodies_per_fish)
        sel = np.flatnonzero(body_on[m.sphere_body])
        centres = sphere_centres(self._pos, self._rot, m.sphere_body[sel], m.sphere_local[sel])
        force = adhesion_forces(centres, m.sphere_radius[sel], m.sphere_body[sel], self._fish_of_body,
                                len(self._pos), adhesion)
        prev = self._adhesion_force
        if prev is None or prev.shape != force.shape:
            prev = np.zeros_like(force)
        for b in np.flatnonzero(np.any(force != prev, axis=1)):
            fm = m.fish[b // m.bodies_per_fish]
            m.mbs.SetLoadParameter(fm.adhesion_loads[b % m.bodies_per_fish], "loadVector", list(force[b]))
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
        self._pos = np.ascontiguousarray(coords[:, :3])  # as the photo-eyes' kernel reads it
        self._rot = rotation_matrices(coords)  # from the rotation vectors in columns 3-5
        self._vel = vel[:, :3]
        self._omega_local = vel[:, 3:]
        self._body_vel = vel  # (n_bodies, 6) velocity and body-frame angular velocity, as the joints' kernel reads them
        for published in (self._pos, self._rot, self._vel, self._omega_local):  # new each step, published as they are
            published.setflags(write=False)
        self._velocities = v  # the belt and device bodies' too: what the equipment reads of the step

    def _sensors(self, step: Step) -> PlantOutputs:
        """What the equipment reads after the solve: every output of the step."""
        seen = Seen(self._pos, self._rot, self._roster.on_line_slots(self.model.bodies_per_fish), self._velocities,
                    self._top_view, self._roster.rejected_by)
        fields: dict[str, dict] = {}
        for equipment in self._equipment.values():
            fields.update(equipment.after_solve(step, seen))
        return PlantOutputs(t_s=self.t_s, **fields)

    def _top_view(self) -> TopView:
        slots = np.flatnonzero(self._roster.on_line_slots())
        return fish_seen_from_above(self.model, self._pos, self._rot, slots, self._member[slots],
                                    (self._tip_bodies[slots], self._tip_local[slots]),
                                    (self._pose_bodies[slots, :1], self._pose_local[slots, :1]))

    def _retire_fish(self) -> None:
        """Fish past the end of the line (or fallen off its end) or through a device's exit are parked; the next
        rebuild drops them (plant.sim.roster decides which and when). Checked every tenth step: a fish takes far
        longer than that to clear the end of the line or a device's exit zone."""
        if self._steps % 10:
            return
        on = self._roster.on_line_slots()
        if not np.any(on):
            return
        through = np.full(len(on), -1)  # the index of the device that takes each fish, -1 for none
        mid = self._pos[self._pose_bodies[:, 0]] + np.einsum("mij,mj->mi", self._rot[self._pose_bodies[:, 0]],
                                                             self._pose_local[:, 0])
        for equipment in self._equipment.values():
            if (taken := equipment.takes(mid, on)) is not None:
                through = np.where(through >= 0, through, taken)
        slots = self._roster.leaving(self._pos.reshape(-1, self.model.bodies_per_fish, 3), self._line,
                                     self._params.retire_after_m, through)
        if not len(slots):
            return
        parks = park_positions(self._line, len(self.model.fish))
        for slot in slots:
            self._place(int(slot), parks[slot], np.eye(3), [0.0, 0.0, 0.0])  # parked: at rest, gravity off
            self._roster.retired(int(slot), int(through[slot]))
        # the rebuild the retirements make due is made after the step's state is published (build_ahead, or the next
        # step): the same state goes into it, and a served step publishes without waiting for it
        self._retired_rebuild_due = self._roster.rebuild_due()
        self._read_state()

    def _rebuild_for_retired(self) -> None:
        if self._retired_rebuild_due:
            self._retired_rebuild_due = False
            self._rebuild(self.t_s)

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
            t_s=self.t_s, fish_ids=self._fish_ids, status=self.status.copy(), member=self._member,
            fish_of_body=self._fish_of_body, pos=self._pos, rot=self._rot, vel=self._vel,
            omega_local=self._omega_local, body_mass_kg=self._body_mass, body_inertia=self._body_inertia,
            fish_mass_kg=self._fish_mass_kg, gravity_mps2=self._gravity, adhesion_force_n=self._adhesion_force,
            outputs=outputs, pose_bodies=self._pose_bodies, pose_local=self._pose_local, geometry=self._geometry,
            drop_adjustments=self._roster.drop_adjustments, rejected_by=self._roster.rejected_by.copy(),
            timings_s=dict(self._timings_s), body_on=self._roster.on_line_slots(self.model.bodies_per_fish),
            **{k: v for e in self._equipment.values() for k, v in e.published().items()})

    def _check_health(self) -> None:
        s = self._state
        body_on = s.on_line_bodies()
        if not body_on.any() or all_clear_on_line(s.pos, self._body_vel, body_on, self._line):
            return  # most steps: no body near a bound
        if body_on.all():  # the full check, without copies when every body in the system is on the line
            check_health(s.pos, s.vel, s.fish_of_body, s.fish_ids, self._line, s.t_s)
        else:
            check_health(s.pos[body_on], s.vel[body_on], s.fish_of_body[body_on], s.fish_ids, self._line, s.t_s)
