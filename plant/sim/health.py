"""Energy watch: a blow-up shows as fish gaining energy that nothing supplied.

The plant already stops on a non-finite state, a fish faster than 25 m/s, a fish outside the
guides or below a belt (:func:`check_health`, after every plant step).  A numerical instability starts
well below those limits; what gives it away early is energy.  The only sources of energy of the
fish are

- the belts: a belt surface moving at v pushes the fish with the force ``load_force`` it measures
  (the belt body's momentum change over the step), so it does the work ``load_force * v * dt``;
- gravity, as potential energy (counted in the fish's energy, so a falling fish gains nothing);
- a fish entering the line brings its energy at release (its drop height); a fish leaving takes
  its energy with it;
- with the ``adhesion`` extension on, the attraction between touching fish: counted as at most
  ``|F . v| dt`` per body.

- the devices (gates, pushers, diverters): the work their bodies did on the fish over the step, from their momentum
  change (:meth:`plant.sim.devices.DeviceActuators.work_on_fish_j`), like the belts'.

Guides and the end plate are fixed and do no work; contact and joint dampers and friction slip
only take energy out.  Contact and joint springs store some for a moment (a landing fish) and give
it back, so the check allows the fish that much: :func:`spring_reserve_j`.

The watch reads only the plant's published state (:class:`plant.sim.state.PlantState`, ``plant.sim.state``
after each step): positions, velocities, masses, gravity, the adhesion forces and the belt speeds
and loads of the step.

So, with E the kinetic (translation and rotation) plus potential energy of the fish on the line,
the watch keeps a bound B on E: B grows by the belts' work and the energy of entering fish, falls
by that of leaving fish, and is lowered to E whenever E is below it (what was dissipated cannot
come back).  ``E - B`` above the spring reserve is energy from nowhere: a blow-up, reported within
the communication step in which it happens, naming the fish that gained the most.

Calibration: in the shipped scenarios (``paper_dump`` seeds 1-4 and a 50-fish drop,
``gap_control`` seeds 1-3) the largest ``E - B`` was 1.6 J; with every model extension on, or a
5 degree incline, 2.5 J (``pytest -m slow`` keeps the shipped scenarios, seeds 1-3, below 30 % of
the reserve); an integration step of 5 or 10 ms
(unstable) is caught one or two communication steps before a fish reaches 25 m/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from plant.contract.devices import going_out_sideways, in_exit_regions
from plant.errors import SimulationError
from plant.sim import kernels
from plant.sim.state import PlantState

MAX_SPEED_MPS = 25.0
"""Anything faster than this in a fish plant is a numerical blow-up, not physics."""


@dataclass(frozen=True)
class _LineBounds:
    """What the health checks read of a line, as arrays (made once per line, not every step)."""

    starts: np.ndarray
    ends: np.ndarray
    z_top: np.ndarray
    slope: np.ndarray
    highest_top_m: float
    """The highest point of any belt top (as :func:`floor_below` works it out): no floor lies above it."""
    y_inside_m: tuple[float, float]
    """(right, left): no guide comes further in than these."""
    x_range_m: tuple[float, float]
    """The line's start and end."""

    @cached_property
    def clear_bounds(self) -> tuple[float, ...]:
        """What every body keeps to be all clear (:func:`_all_clear`): (from x, to x for the guides, to x for the
        belts, y above, y below, z above, squared speed below).  The x range is where :func:`check_health` looks at
        the guides (x from the line's start - 0.1 m to its end) and the belts (to 0.1 m before the end), widened by
        the margin."""
        margin = 1e-9  # rounding: the full check decides anything this near a bound
        x_start, x_end = self.x_range_m
        return (x_start - 0.1 - margin, x_end + margin, x_end - 0.1 + margin, self.y_inside_m[0] - 0.05 + margin,
                self.y_inside_m[1] + 0.05 - margin, self.highest_top_m - 0.08 + margin, (MAX_SPEED_MPS - margin) ** 2)


_bounds_cache: tuple = (None, None)  # (line, its _LineBounds): one line a run; holding it keeps its id unique


def _line_bounds(line) -> _LineBounds:
    global _bounds_cache
    cached = _bounds_cache  # one read: plants in threads each see a whole pair
    if cached[0] is line:
        return cached[1]
    starts = np.array([c.x_start_m for c in line.conveyors])
    ends = np.array([c.x_end_m for c in line.conveyors])
    z_top = np.array([c.z_top_m for c in line.conveyors])
    slope = np.tan(np.radians([c.incline_deg for c in line.conveyors]))
    highest = float(np.max(z_top + np.maximum(0.0, (ends - starts) * slope)))
    if line.guides is None:
        inside = (-0.5 * line.guide_width_m, 0.5 * line.guide_width_m)
    else:
        inside = (max(y for _, y in line.guides.right), min(y for _, y in line.guides.left))
    bounds = _LineBounds(starts, ends, z_top, slope, highest, inside, (line.x_start_m, line.x_end_m))
    _bounds_cache = (line, bounds)
    return bounds


def floor_below(line, x_m: np.ndarray) -> np.ndarray:
    """Lowest belt top of ``line`` (a :class:`plant.contract.line.Line`) within 0.1 m of each x: where a fish
    can lie, drape or hang over a drum (``inf`` where no belt is that near)."""
    x = np.asarray(x_m, dtype=float)[:, None]
    lb = _line_bounds(line)
    starts, ends, z_top, slope = lb.starts, lb.ends, lb.z_top, lb.slope
    z = z_top[None, :] + np.clip(x - starts[None, :], 0.0, (ends - starts)[None, :]) * slope[None, :]
    near = (x >= starts[None, :] - 0.1) & (x <= ends[None, :] + 0.1)
    return np.where(near, z, np.inf).min(axis=1)


def check_health(pos: np.ndarray, vel: np.ndarray, fish_of: np.ndarray, fish_ids, line, t_s: float) -> None:
    """Raise SimulationError, naming the fish, on a body of a fish on the line that is non-finite,
    faster than :data:`MAX_SPEED_MPS`, outside the guides or fallen through a belt.

    ``pos`` and ``vel`` (n, 3) are those bodies' positions and velocities, ``fish_of`` (n,) each
    body's fish as an index into ``fish_ids``; ``line`` the :class:`plant.contract.line.Line`; ``t_s`` the
    time reported with the error.  A body over the last 0.1 m of the line (hanging over the end drum)
    or past its end is not checked against the belts: a fish leaving the line over the end; nor is one at a device
    that takes fish off the line (through a gate's gap, out of a pusher's or diverter's opening).  Beyond a guide a
    body may be only at an opening in it, or when its fish is going out through one (some of it beyond the guide
    there): anywhere else a fish outside the guides went through a wall."""
    if len(pos) == 0 or _all_clear(pos, vel, _line_bounds(line)):
        return
    bad = ~np.all(np.isfinite(pos), axis=1) | ~np.all(np.isfinite(vel), axis=1)
    if np.any(bad):
        raise SimulationError(f"numerical blow-up: fish '{fish_ids[fish_of[bad][0]]}' has "
                              "non-finite position or velocity", t_s)
    speed = np.linalg.norm(vel, axis=1)
    if np.any(speed > MAX_SPEED_MPS):
        i = int(np.argmax(speed))
        raise SimulationError(f"numerical blow-up: fish '{fish_ids[fish_of[i]]}' moves at "
                              f"{speed[i]:.1f} m/s", t_s)
    within_x = (pos[:, 0] >= line.x_start_m - 0.1) & (pos[:, 0] <= line.x_end_m)
    left, right = line.guide_y_at(pos[:, 0])
    outside = within_x & ((pos[:, 1] > left + 0.05) | (pos[:, 1] < right - 0.05))
    if np.any(outside) and line.devices:  # rare: only then look for a device's opening (a pusher's or diverter's)
        outside &= ~(in_exit_regions(line, pos[:, 0], pos[:, 1]) | going_out_sideways(line, pos[:, 0], pos[:, 1], fish_of))
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        guides = (f"guides at +-{left[i]:g} m" if line.guides is None else
                  f"at x = {pos[i, 0]:.3f} m, guides there at y = {right[i]:.3f} and {left[i]:.3f} m")
        raise SimulationError(f"fish '{fish_ids[fish_of[i]]}' left the line sideways (y = {pos[i, 1]:.3f} m, "
                              f"{guides})", t_s)
    floor = floor_below(line, pos[:, 0])
    # a fish sliding off the end of the line hangs over the last drum, and one leaving slowly drops
    # and tumbles beside it: only a fish wholly clear of that drum (as floor_below counts it, 0.1 m)
    # can have gone through a belt
    below = within_x & (pos[:, 2] < floor - 0.08)
    if np.any(below):  # rare: only then look at the whole fish (this runs every step)
        fish_max_x = np.full(int(fish_of.max()) + 1, -np.inf)
        np.maximum.at(fish_max_x, fish_of, pos[:, 0])
        below &= fish_max_x[fish_of] < line.x_end_m - 0.1
        if line.devices:  # a gate's fish drop through its gap, a pusher's or diverter's off the belt's side
            below &= ~in_exit_regions(line, pos[:, 0], None)
    if np.any(below):
        i = int(np.flatnonzero(below)[0])
        raise SimulationError(f"fish '{fish_ids[fish_of[i]]}' fell through a belt "
                              f"(z = {pos[i, 2]:.3f} m at x = {pos[i, 0]:.3f} m)", t_s)


def _all_clear(pos: np.ndarray, vel: np.ndarray, lb: _LineBounds) -> bool:
    """True when no body can fail :func:`check_health`, from a few bounds: all finite (min and max carry a NaN or an
    infinity), slower than the limit, inside the narrowest guides where the guides are checked and less than 8 cm
    below the highest belt top where the belts are (not over the end drum: a fish leaving the line hangs and drops
    there); otherwise the full check looks closer."""
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    top_speed2 = float(np.max(np.einsum("ij,ij->i", vel, vel)))  # NaN or inf stays so
    x_from, x_guides_to, x_belts_to, y_low, y_high, z_low, speed2_max = lb.clear_bounds
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and top_speed2 < speed2_max):
        return False
    x, y = pos[:, 0], pos[:, 1]
    guided = (x >= x_from) & (x <= x_guides_to)
    return not (guided & ((y <= y_low) | (y >= y_high) | ((x < x_belts_to) & (pos[:, 2] <= z_low)))).any()


def all_clear_on_line(pos: np.ndarray, velocities: np.ndarray, body_on: np.ndarray, line) -> bool:
    """:func:`_all_clear` over the bodies on the line (``body_on``), in one pass (plant.sim.kernels): the plant's
    check after most steps.  ``velocities`` (n, 6): each body's velocity, then its angular velocity."""
    return kernels.all_clear(pos, velocities, body_on, _line_bounds(line).clear_bounds)


RESERVE_MIN_J = 8.0
RESERVE_J_PER_KG = 0.5
"""Spring reserve: what contact and joint springs may hold and give back, 8 J plus 0.5 J per kg of
fish on the line.  A fish draped over another bends its soft joints (they sag half their range
under the fish's own weight) and gives that energy back as it straightens: the largest rise
without a source seen in normal runs (see above) is at least 3 times below this reserve, at
least 6 times in the shipped scenarios as they are.  A blow-up grows by orders of magnitude
within a few steps and crosses it at once."""


def spring_reserve_j(mass_on_line_kg: float) -> float:
    """Energy [J] the fish may gain beyond what the belts supply before it is called a blow-up."""
    return RESERVE_MIN_J + RESERVE_J_PER_KG * mass_on_line_kg


@dataclass
class EnergyWatch:
    """Checks after every communication step that the fish gained no energy without a source.

    >>> watch = EnergyWatch()   # then, after each plant step: watch.check(plant.state, dt_s)
    """

    worst_excess_j: float = 0.0
    """Largest ``E - B`` seen so far [J] (for calibration)."""
    worst_ratio: float = 0.0
    """Largest ``(E - B) / reserve`` seen so far."""
    last_excess_j: float = 0.0
    """``E - B`` after the last step [J]."""
    worst_j_per_kg: float = 0.0
    """Largest ``(E - B) / mass of the fish on the line`` seen so far [J/kg]."""
    _energy: np.ndarray | None = None
    """Energy of each fish after the last step (NaN: not on the line)."""
    _lowest: np.ndarray | None = None
    """Lowest energy of each fish since it came onto the line."""
    _bound_j: float = 0.0
    _layout: _Layout | None = None
    """The system's fish as of the last step, while no fish came or went (the quick path of :meth:`check`)."""

    @staticmethod
    def fish_energy(state: PlantState) -> np.ndarray:
        """Kinetic plus potential energy [J] of every fish in ``state`` (NaN for fish not on the line)."""
        n = len(state.status)
        on = state.on_line_bodies()
        if not on.any():
            return np.full(n, np.nan)
        on = slice(None) if on.all() else on  # most steps: every body in the system, no copies
        m, inertia = state.body_mass_kg[on], state.body_inertia[on]
        vel = state.vel[on]
        e = (0.5 * m * np.einsum("ij,ij->i", vel, vel)
             + 0.5 * np.einsum("ij,ij->i", inertia, state.omega_local[on] ** 2)
             - m * (state.pos[on] @ state.gravity_mps2))
        fish = state.fish_of_body[on]
        total = np.bincount(fish, weights=e, minlength=n)
        total[np.bincount(fish, minlength=n) == 0] = np.nan
        return total

    @staticmethod
    def _adhesion_power_bound(state: PlantState) -> float:
        force, vel = state.adhesion_force_n, state.vel
        if force is None or force.shape != vel.shape or not np.any(force):
            return 0.0
        return float(np.abs(np.einsum("ij,ij->i", force, vel)).sum())

    @classmethod
    def _work_j(cls, state: PlantState, dt_s: float) -> float:
        """What the sources did on the fish during the step: the belts (load times speed), at most the adhesion
        forces' power, the devices' work."""
        out = state.outputs
        work = dt_s * sum(out.belt_load_force_n[c] * out.belt_speed_mps[c] for c in out.belt_speed_mps)
        return work + (dt_s * cls._adhesion_power_bound(state) + state.device_work_j)  # as summed before

    def after_step(self, state: PlantState, outputs: object, inputs: object, dt_s: float) -> None:
        """As a step observer (:mod:`plant.sim.observers`): :meth:`check` after each step."""
        self.check(state, dt_s)

    def check(self, state: PlantState, dt_s: float) -> None:
        """Call after each plant step of ``dt_s`` with the state it published (its outputs: the step's belt
        speeds and loads); raises SimulationError on energy from nowhere."""
        if self._quick_check(state, dt_s):
            return
        if self._layout is not None:  # the quick steps before kept the energies of the system's fish alone
            self._energy, self._lowest = self._layout.per_fish(len(state.status))
            self._layout = None
        now = self.fish_energy(state)
        before = self._energy if self._energy is not None else np.full(len(now), np.nan)
        on_now, on_before = ~np.isnan(now), ~np.isnan(before)
        work = self._work_j(state, dt_s)
        entered = float(now[on_now & ~on_before].sum())
        left = float(before[on_before & ~on_now].sum())
        bound = self._bound_j + work + entered - left
        total = float(now[on_now].sum())
        self._lowest = np.where(on_now, np.fmin(self._lowest, now) if self._lowest is not None else now, np.nan)
        self._energy = now
        if not on_now.any():
            self._bound_j = 0.0
            return
        mass = float(state.fish_mass_kg[on_now].sum())
        reserve = spring_reserve_j(mass)
        excess = total - bound if np.isfinite(total) else np.inf
        self.last_excess_j = excess
        self.worst_excess_j = max(self.worst_excess_j, excess)
        self.worst_ratio = max(self.worst_ratio, excess / reserve)
        self.worst_j_per_kg = max(self.worst_j_per_kg, excess / mass if mass > 0 else 0.0)
        if excess > reserve:
            gains = np.where(on_now, now - self._lowest, -np.inf)
            k = int(np.argmax(np.nan_to_num(gains, nan=np.inf)))
            fish_id = state.fish_ids[k]
            raise SimulationError(
                f"numerical blow-up: the fish gained {excess:.1f} J more energy than the belts supplied "
                f"(allowed {reserve:.1f} J for the springs), most of it fish '{fish_id}' "
                f"(+{gains[k]:.1f} J since its lowest)", state.t_s)
        self._bound_j = min(bound, total)
        self._layout = _Layout.of(state, now, self._lowest)

    def _quick_check(self, state: PlantState, dt_s: float) -> bool:
        """:meth:`check` for a step in which no fish came or went (most steps): the same bound from the fish in the
        system alone (a run's hundreds of others take no part) with their masses and gravity's terms kept; False
        (nothing done) when the fish changed, an energy is not finite or the excess would fail the check (the full
        check then says so)."""
        lay = self._layout
        if lay is None or state.body_on is not lay.body_on or state.body_mass_kg is not lay.body_mass_kg:
            return False
        x = np.concatenate((state.vel, state.omega_local, state.pos), axis=1)  # (n, 9): one pass for all terms
        if lay.bodies is not None:
            x = x[lay.bodies]
        now = (x * (x * lay.square + lay.linear)).reshape(len(lay.fish), -1).sum(axis=1)
        total = float(now.sum())
        bound = self._bound_j + self._work_j(state, dt_s)
        excess = total - bound
        if not np.isfinite(total) or excess > lay.reserve_j:
            return False
        lay.lowest = np.fmin(lay.lowest, now)
        self.last_excess_j = excess
        self.worst_excess_j = max(self.worst_excess_j, excess)
        self.worst_ratio = max(self.worst_ratio, excess / lay.reserve_j)
        self.worst_j_per_kg = max(self.worst_j_per_kg, excess / lay.mass_kg if lay.mass_kg > 0 else 0.0)
        self._bound_j = min(bound, total)
        lay.now = now
        return True


@dataclass
class _Layout:
    """The fish in the system while none comes or goes, for :meth:`EnergyWatch._quick_check`: which bodies are on the
    line (``body_on`` and the masses, by identity: the plant publishes them read-only until a rebuild or a change), the
    energy's coefficients per body and the fish's energies, per slot."""

    body_on: np.ndarray
    body_mass_kg: np.ndarray
    bodies: np.ndarray | None
    """The bodies on the line (None: all of them)."""
    fish: np.ndarray
    """The fish index of each slot on the line."""
    square: np.ndarray
    """(n, 9) each body's energy per square of its velocity and angular velocity components (half its mass and
    moments of inertia; 0 for its position)."""
    linear: np.ndarray
    """(n, 9) its potential energy per unit of each position component (minus its weight; 0 for the velocities)."""
    mass_kg: float
    reserve_j: float
    now: np.ndarray
    lowest: np.ndarray

    @classmethod
    def of(cls, state: PlantState, energy: np.ndarray, lowest: np.ndarray) -> _Layout | None:
        """From a state the full check has just judged, with its per-fish energies (None without a published
        on-line mask or fish on the line)."""
        body_on = state.body_on
        if body_on is None or not body_on.any():
            return None
        sel = None if body_on.all() else np.flatnonzero(body_on)
        pick = (lambda a: a) if sel is None else (lambda a: a[sel])
        fish = state.member[body_on[::state.bodies_per_fish]]
        if np.isnan(energy[fish]).any():
            return None
        m = pick(state.body_mass_kg)
        mass = float(state.fish_mass_kg[fish].sum())
        zeros = np.zeros((len(m), 3))
        square = np.hstack((np.repeat(0.5 * m[:, None], 3, axis=1), 0.5 * pick(state.body_inertia), zeros))
        linear = np.hstack((zeros, zeros, -m[:, None] * state.gravity_mps2[None, :]))
        return cls(body_on, state.body_mass_kg, sel, fish, square, linear, mass, spring_reserve_j(mass),
                   energy[fish], lowest[fish])

    def per_fish(self, n_fish: int) -> tuple[np.ndarray, np.ndarray]:
        """The energies and lowest energies of every fish of the run (NaN: not on the line), as the full check keeps
        them."""
        energy, lowest = np.full(n_fish, np.nan), np.full(n_fish, np.nan)
        energy[self.fish], lowest[self.fish] = self.now, self.lowest
        return energy, lowest
