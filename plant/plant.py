"""Stepping the plant from outside, one communication step at a time (the co-simulation interface).

>>> from plant.line import Line
>>> line = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
...     {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "photoeyes": [{"id": "pe1", "x_m": 1.5, "z_m": 0.015}]})
>>> plant = Plant(line, fish=[])
>>> out = plant.step({"c1": 0.3})
>>> round(plant.t_s, 3), out.photoeyes["pe1"], sorted(plant.input_ports())
(0.01, False, ['c1.speed'])

One step is a short, fixed pipeline (read it top to bottom):

1. release the fish whose drop time has come (placed clear of the fish already there);
2. set the belt speeds (each belt body back in place, moving at its speed);
3. re-linearise the joints that are at or running into their limits;
4. let Exudyn integrate to the end of the step;
5. read the state, work out the sensors, retire fish that have left the line, check health.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plant.errors import SimulationError
from plant.joints import linearize, stack_laws
from plant.line import Line
from plant.model import BELT_MASS_KG, build_model, pose_coordinates
from plant.params import PlantParams
from plant.population import FishSpec
from plant.rotations import lying_orientation, matrix_to_rotvec, rotvec_to_matrix
from plant.sensors import belt_loads, fish_pose, photoeyes_blocked, sphere_centres, spine_point_local

WAITING, ON_LINE, LEFT = 0, 1, 2
MAX_SPEED_MPS = 25.0
"""Anything faster than this in a fish plant is a numerical blow-up, not physics."""


@dataclass
class PlantOutputs:
    """Sensor readings at the end of a communication step."""

    t_s: float
    belt_speed_mps: dict[str, float]
    belt_load_force_n: dict[str, float]
    belt_load_mass_kg: dict[str, float]
    photoeyes: dict[str, bool]

    def port_values(self) -> dict[str, float | bool]:
        """Every output as ``"<id>.<signal>"`` (the names connections use)."""
        out: dict[str, float | bool] = {}
        for cid in self.belt_speed_mps:
            out[f"{cid}.speed"] = self.belt_speed_mps[cid]
            out[f"{cid}.load_force"] = self.belt_load_force_n[cid]
            out[f"{cid}.load_mass"] = self.belt_load_mass_kg[cid]
        for pid, blocked in self.photoeyes.items():
            out[f"{pid}.blocked"] = blocked
        return out


@dataclass
class FishState:
    """Poses of all fish at the end of the last step (measured-data frame)."""

    t_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    yaw_rad: np.ndarray
    status: np.ndarray
    """WAITING (not dropped yet), ON_LINE, or LEFT (gone past the end of the line)."""


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
        n_sub = comm_step_s / self.params.numerics.step_s
        if abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise ValueError(f"communication step {comm_step_s} s is not a whole multiple of the integration "
                             f"step {self.params.numerics.step_s} s")
        self.comm_step_s = comm_step_s
        self.model = build_model(line, self.fish_specs, self.params, joint_factors)
        self.conveyor_ids = [c.id for c in line.conveyors]
        self.photoeye_ids = [p.id for p in line.photoeyes]
        self._beams = np.array([[p.x_m, p.z_m] for p in line.photoeyes]).reshape(-1, 2)
        self._x_ends = np.array([c.x_end_m for c in line.conveyors])
        self._x_starts = np.array([c.x_start_m for c in line.conveyors])
        self._z_top = np.array([c.z_top_m for c in line.conveyors])
        self.status = np.full(len(self.fish_specs), WAITING, dtype=np.int8)
        self.drop_adjustments: list[DropAdjustment] = []
        self._steps = 0
        self._belt_speed = np.zeros(len(self.conveyor_ids))
        self._gravity = self.params.gravity_mps2 * np.array(
            [np.sin(np.radians(self.params.incline_deg)), 0.0, -np.cos(np.radians(self.params.incline_deg))])
        self._pose_refs = [(spine_point_local(f.geometry, 0.5), spine_point_local(f.geometry, 0.2),
                            spine_point_local(f.geometry, 0.8)) for f in self.model.fish]
        n_joints = 4 * len(self.fish_specs)
        self._laws = stack_laws([f.laws for f in self.model.fish])
        self._k_now = self._laws.k_soft.copy()
        self._offset_now = np.zeros((n_joints, 3))
        self._joint_bodies = np.array([(f.first_body + j, f.first_body + j + 1)
                                       for f in self.model.fish for j in range(4)], dtype=np.int64).reshape(-1, 2)
        self._sphere_active = np.zeros(len(self.model.sphere_body), dtype=bool)
        self._fish_of_body = np.repeat(np.arange(len(self.fish_specs)), 5)

        import exudyn as exu
        self._solver = exu.MainSolverExplicit()
        ss = self.model.settings
        ss.timeIntegration.endTime = 1.0e6  # extended chunk by chunk
        ss.timeIntegration.numberOfSteps = int(round(1.0e6 / self.params.numerics.step_s))
        self._solver.InitializeSolver(self.model.mbs, ss)
        self._read_state()

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

    # ---- the step ----------------------------------------------------------------------------
    def step(self, belt_speeds_mps: dict[str, float] | np.ndarray) -> PlantOutputs:
        """Advance one communication step with the given belt surface speeds."""
        speeds = self._speeds_array(belt_speeds_mps)
        t_end = (self._steps + 1) * self.comm_step_s
        self._release_due_fish(self.t_s + 1e-9)
        self._set_belts(speeds)
        self._relinearize_joints()
        self._solver.it.endTime = t_end
        self._solver.SolveSteps(self.model.mbs, self.model.settings)
        self._steps += 1
        self._read_state()
        outputs = self._sensors(speeds)
        self._retire_fish()
        self._check_health()
        return outputs

    # ---- 1. drops ----------------------------------------------------------------------------
    def _release_due_fish(self, t: float) -> None:
        due = [k for k, f in enumerate(self.fish_specs) if self.status[k] == WAITING and f.drop_t_s <= t]
        for k in due:
            self._release(k)
        if due:
            self._read_state()

    def _release(self, k: int) -> None:
        spec = self.fish_specs[k]
        fm = self.model.fish[k]
        rot = lying_orientation(spec.drop_yaw_rad, spec.side)
        mid = np.array([spec.drop_x_m, spec.drop_y_m, 0.0])
        sph = self.model.sphere_body
        mine = (sph >= fm.first_body) & (sph < fm.first_body + 5)
        local_body = sph[mine] - fm.first_body
        # sphere centres of the fish placed with its mid point at z = 0
        centres = (fm.body_offsets_m[local_body] + self.model.sphere_local[mine]) @ rot.T + mid
        radii = self.model.sphere_radius[mine]
        surface = self.line.z_top_at(spec.drop_x_m)
        z_mid = surface + spec.drop_z_m - float(np.min(centres[:, 2] - radii))
        # clear of fish already on the line below it: lowest sphere above their highest, plus the drop height
        others = self._sphere_active & ~mine
        raised = 0.0
        if np.any(others):
            oc, orad = self._centres[others], self.model.sphere_radius[others]
            d_xy = np.linalg.norm(centres[:, None, :2] - oc[None, :, :2], axis=2)
            near = d_xy < (radii[:, None] + orad[None, :] + 0.01)
            if np.any(near):
                top = np.max(np.where(near, oc[None, :, 2] + orad[None, :], -np.inf), axis=1)
                bottoms = z_mid + centres[:, 2] - radii
                need = float(np.max(top + spec.drop_z_m - bottoms))
                if need > 0:
                    z_mid += need
                    raised = need
        if raised > 0:
            self.drop_adjustments.append(DropAdjustment(spec.fish_id, raised))
        mid[2] = z_mid
        idx, values = pose_coordinates(self.model, k, mid, rot)
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        q[idx] = values
        v[idx] = 0.0
        sd.SetODE2Coordinates(q)
        sd.SetODE2Coordinates_t(v)
        for load in fm.gravity_loads:
            self.model.mbs.SetLoadParameter(load, "loadVector", list(self._gravity))
        self.status[k] = ON_LINE

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
        self._belt_speed = speeds

    # ---- 3. joints ---------------------------------------------------------------------------
    def _relinearize_joints(self) -> None:
        if len(self._joint_bodies) == 0:
            return
        a, b = self._joint_bodies[:, 0], self._joint_bodies[:, 1]
        ra, rb = self._rot[a], self._rot[b]
        rel = np.einsum("nji,njk->nik", ra, rb)
        theta = matrix_to_rotvec(rel)
        # relative angular velocity in the frame of body a (node velocities are body-frame)
        w_b_in_a = np.einsum("nij,nj->ni", rel, self._omega_local[b])
        theta_next = theta + (w_b_in_a - self._omega_local[a]) * self.comm_step_s
        k_new, off_new = linearize(self._laws, theta, theta_next)
        idle = np.repeat(self.status != ON_LINE, 4)
        k_new[idle] = self._laws.k_soft[idle]
        off_new[idle] = 0.0
        changed = (np.any(np.abs(k_new - self._k_now) > 0.02 * self._k_now, axis=1)
                   | np.any(np.abs(off_new - self._offset_now) > 0.005, axis=1))
        if not np.any(changed):
            return
        mbs = self.model.mbs
        for j in np.flatnonzero(changed):
            fm = self.model.fish[j // 4]
            conn = fm.connectors[j % 4]
            stiffness = np.array(mbs.GetObjectParameter(conn, "stiffness"))
            stiffness[3:, 3:] = np.diag(k_new[j])
            mbs.SetObjectParameter(conn, "stiffness", stiffness)
            mbs.SetObjectParameter(conn, "offset", [0.0, 0.0, 0.0, *off_new[j]])
        self._k_now[changed] = k_new[changed]
        self._offset_now[changed] = off_new[changed]

    # ---- 5. state, sensors, retirement, health ------------------------------------------------
    def _read_state(self) -> None:
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        coords = q[self.model.body_ltg] + self.model.body_ref
        vel = v[self.model.body_ltg]
        self._pos = coords[:, :3]
        self._rot = rotvec_to_matrix(coords[:, 3:])
        self._vel = vel[:, :3]
        self._omega_local = vel[:, 3:]
        self._belt_vel_end = v[self.model.belt_ltg[:, :3]] if len(self.model.belt_ltg) else np.zeros((0, 3))
        self._centres = sphere_centres(self._pos, self._rot, self.model.sphere_body, self.model.sphere_local)
        self._sphere_active = (self.status == ON_LINE)[self._fish_of_body][self.model.sphere_body] \
            if len(self.fish_specs) else np.zeros(0, dtype=bool)

    def _sensors(self, speeds: np.ndarray) -> PlantOutputs:
        load, mass = belt_loads(self._belt_vel_end, speeds, BELT_MASS_KG, self.comm_step_s, self.params.gravity_mps2)
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
        body_on = (self.status == ON_LINE)[self._fish_of_body]
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
        """Fish past the end of the line (or fallen off its end) are parked and no longer simulated."""
        if not np.any(self.status == ON_LINE):
            return
        pos = self._pos.reshape(-1, 5, 3)
        x_gone = self.line.x_end_m + self.params.retire_after_m
        z_floor = min(c.z_top_m for c in self.line.conveyors) - 0.5
        past = np.all(pos[:, :, 0] > x_gone, axis=1)
        fell_off_end = np.all(pos[:, :, 0] > self.line.x_end_m, axis=1) & np.all(pos[:, :, 2] < z_floor, axis=1)
        retired = np.flatnonzero((self.status == ON_LINE) & (past | fell_off_end))
        for k in retired:
            self._park(int(k))
            self.status[k] = LEFT
        if len(retired):
            self._read_state()

    def _park(self, k: int) -> None:
        fm = self.model.fish[k]
        idx, values = pose_coordinates(self.model, k, fm.park_position, np.eye(3))
        sd = self.model.mbs.systemData
        q = sd.GetODE2Coordinates()
        v = sd.GetODE2Coordinates_t()
        q[idx] = values
        v[idx] = 0.0
        sd.SetODE2Coordinates(q)
        sd.SetODE2Coordinates_t(v)
        for load in fm.gravity_loads:
            self.model.mbs.SetLoadParameter(load, "loadVector", [0.0, 0.0, 0.0])

    def _check_health(self) -> None:
        on = self.status == ON_LINE
        if not np.any(on):
            return
        body_on = on[self._fish_of_body]
        pos, vel = self._pos[body_on], self._vel[body_on]
        fish_of = self._fish_of_body[body_on]
        bad = ~np.all(np.isfinite(pos), axis=1) | ~np.all(np.isfinite(vel), axis=1)
        if np.any(bad):
            raise SimulationError(f"numerical blow-up: fish '{self.fish_specs[fish_of[bad][0]].fish_id}' has "
                                  "non-finite position or velocity", self.t_s)
        speed = np.linalg.norm(vel, axis=1)
        if np.any(speed > MAX_SPEED_MPS):
            i = int(np.argmax(speed))
            raise SimulationError(f"numerical blow-up: fish '{self.fish_specs[fish_of[i]].fish_id}' moves at "
                                  f"{speed[i]:.1f} m/s", self.t_s)
        within_x = (pos[:, 0] >= self.line.x_start_m - 0.1) & (pos[:, 0] <= self.line.x_end_m)
        half = 0.5 * self.line.guide_width_m
        outside = within_x & (np.abs(pos[:, 1]) > half + 0.05)
        if np.any(outside):
            i = int(np.flatnonzero(outside)[0])
            raise SimulationError(f"fish '{self.fish_specs[fish_of[i]].fish_id}' left the line sideways "
                                  f"(y = {pos[i, 1]:.3f} m, guides at +-{half:g} m)", self.t_s)
        floor = self.floor_below(pos[:, 0])
        below = within_x & (pos[:, 2] < floor - 0.08)
        if np.any(below):
            i = int(np.flatnonzero(below)[0])
            raise SimulationError(f"fish '{self.fish_specs[fish_of[i]].fish_id}' fell through a belt "
                                  f"(z = {pos[i, 2]:.3f} m at x = {pos[i, 0]:.3f} m)", self.t_s)

    def floor_below(self, x_m: np.ndarray) -> np.ndarray:
        """Lowest belt top within 0.1 m of each x: where a fish can lie, drape or hang over a drum."""
        x = np.asarray(x_m, dtype=float)[:, None]
        near = (x >= self._x_starts[None, :] - 0.1) & (x <= self._x_ends[None, :] + 0.1)
        return np.where(near, self._z_top[None, :], np.inf).min(axis=1)

    # ---- state for recording -----------------------------------------------------------------
    def fish_state(self) -> FishState:
        n = len(self.fish_specs)
        x, y, z, yaw = (np.full(n, np.nan) for _ in range(4))
        for k in np.flatnonzero(self.status == ON_LINE):
            fm = self.model.fish[k]
            sl = slice(fm.first_body, fm.first_body + 5)
            p, h = fish_pose(self._pos[sl], self._rot[sl], *self._pose_refs[k])
            x[k], y[k], z[k], yaw[k] = p[0], p[1], p[2], h
        return FishState(self.t_s, x, y, z, yaw, self.status.copy())

    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n_bodies, 3), rotation matrices (n_bodies, 3, 3)) of all fish bodies."""
        return self._pos.copy(), self._rot.copy()

    def body_velocities(self) -> np.ndarray:
        return self._vel.copy()
