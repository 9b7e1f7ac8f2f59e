"""The run's fish roster: which fish waits, which is in the system and where, which is on the line, which is gone.

The plant keeps only the fish in play in its Exudyn system (:mod:`plant.sim.model`: every contact sphere costs time
whether it touches anything or not).  The roster decides which: the fish due within :data:`ADMIT_AHEAD_S` are admitted
together (fewer rebuilds; they wait parked below the line, gravity off), a fish whose drop time has come is released
onto the line, a fish past the line's end, fallen off it or gone through a device's exit is retired (parked; the next
rebuild drops it), and the system is rebuilt when fish are to be admitted or a quarter of those in it are gone.  The
plant carries out what it decides against the system (placing, parking, rebuilding); the roster holds no Exudyn item.

>>> import numpy as np
>>> from plant.fish.population import FishSpec
>>> fish = [FishSpec(f"f{i}", 0.7, 0.12, 0.08, 3.0, 2.0, t, 0.3, 0.0, 0.0, 0.05) for i, t in ((1, 0.5), (2, 3.0))]
>>> roster = FishRoster.of(fish)
>>> roster.due(0.6), roster.due(2.5, ADMIT_AHEAD_S), roster.must_admit(roster.due(0.6))
([0], [0, 1], True)
>>> roster.seated(np.array([0])); roster.must_admit(roster.due(0.6))
False
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plant.contract.line import Line
from plant.fish.population import FishSpec
from plant.sim.state import DropAdjustment, FishStatus

WAITING, ON_LINE, LEFT, REJECTED = FishStatus.WAITING, FishStatus.ON_LINE, FishStatus.LEFT, FishStatus.REJECTED
ADMIT_AHEAD_S = 1.0
"""Fish due within this time are put into the system together (fewer rebuilds); they wait parked."""


@dataclass
class FishRoster:
    """Every fish of the run: where it is (:class:`~plant.sim.state.FishStatus`), which device took it, the drops
    raised to clear the fish below, and which slot of the system holds it."""

    fish_ids: tuple[str, ...]
    drop_t_s: np.ndarray
    """(n_fish,) when each is due; one comparison a step."""
    status: np.ndarray
    """(n_fish,) int8 :class:`~plant.sim.state.FishStatus`."""
    rejected_by: np.ndarray
    """(n_fish,) the index of the device that took each off the line, -1 for none."""
    drop_adjustments: tuple[DropAdjustment, ...] = ()
    member: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(n_slots,) the fish in each slot of the system."""
    slot_of: dict[int, int] = field(default_factory=dict)
    """Fish index -> its slot, for the fish in the system."""
    # read several times every step, changed only when a fish comes or goes: kept until then
    _next_drop_t_s: float | None = field(default=None, init=False, repr=False)
    _on_line: dict[int, np.ndarray] = field(default_factory=dict, init=False, repr=False)

    @classmethod
    def of(cls, fish: list[FishSpec]) -> FishRoster:
        n = len(fish)
        return cls(tuple(f.fish_id for f in fish), np.array([f.drop_t_s for f in fish], dtype=float),
                   np.full(n, WAITING, dtype=np.int8), np.full(n, -1, dtype=np.int64))

    def seated(self, member: np.ndarray) -> None:
        """The system was (re)built with these fish in its slots."""
        self.member = member
        self.slot_of = {int(k): i for i, k in enumerate(member)}
        self._on_line.clear()

    def due(self, t_s: float, ahead_s: float = 0.0) -> list[int]:
        """The waiting fish whose drop comes by ``t_s + ahead_s``."""
        if self._next_drop_t_s is None:
            waiting = self.drop_t_s[self.status == WAITING]
            self._next_drop_t_s = float(waiting.min()) if len(waiting) else np.inf
        if t_s + ahead_s < self._next_drop_t_s:  # most steps: none due
            return []
        return [int(k) for k in np.flatnonzero((self.status == WAITING) & (self.drop_t_s <= t_s + ahead_s))]

    def must_admit(self, due: list[int]) -> bool:
        """Whether some of ``due`` is not in the system yet (it must be rebuilt with them)."""
        return any(k not in self.slot_of for k in due)

    def next_rebuilds(self, steps: int, step_s: float, rear_x_m: np.ndarray) -> list[list[int]]:
        """The fish the next rebuilds may hold, in their order, as far as they can be foreseen (step ``k`` at
        ``t = k step_s``, ``steps`` made so far; ``rear_x_m``: each slot's rearmost point along the line): the next
        admission's (its time is known), then the next retirement's (a guess); either may come first."""
        plans = [admission] if (admission := self._next_admission(steps, step_s)) else []
        if (retirement := self._next_retirement(rear_x_m, steps * step_s)) and retirement not in plans:
            plans.append(retirement)
        return plans

    def _next_admission(self, steps: int, step_s: float) -> list[int]:
        """The fish of the next rebuild that admits fish, if no fish leaves the line before it: those on the line
        then in their slots' order, then those it admits or keeps parked, as :meth:`due` will give them; none if no
        fish waits outside the system."""
        waiting = self.status == WAITING
        outside = waiting.copy()
        outside[self.member] = False
        if not outside.any():
            return []
        t_next = float(self.drop_t_s[outside].min())
        k = max(steps, int((t_next - 1e-9) / step_s) - 1)
        while k * step_s + 1e-9 < t_next:  # the plant admits at its step k's start, t = k step_s (+ 1e-9)
            k += 1
        released = waiting & (self.drop_t_s <= (k - 1) * step_s + 1e-9) if k > steps else np.zeros_like(waiting)
        on_line = [int(m) for m in self.member if self.status[m] == ON_LINE or released[m]]
        due = np.flatnonzero(waiting & ~released & (self.drop_t_s <= (k * step_s + 1e-9) + ADMIT_AHEAD_S))
        return on_line + [int(m) for m in due]

    def _next_retirement(self, rear_x_m: np.ndarray, t_s: float) -> list[int]:
        """The fish of the next rebuild that fish leaving the line make due, if those that leave are the ones furthest
        downstream (as many as it takes; a pile's leave together) and leave about ``t_s``: those on the line but them,
        in their slots' order, then the fish due then; none if too few are on the line."""
        on = self.on_line_slots()
        more = self._gone_for_rebuild() - self._gone()  # as rebuild_due counts
        if more < 1 or int(np.sum(on)) <= more:
            return []
        leaving = np.argsort(np.where(on, -rear_x_m, np.inf), kind="stable")[:more]
        return [int(k) for s, k in enumerate(self.member) if on[s] and s not in leaving] + self.due(t_s, ADMIT_AHEAD_S)

    def on_line_slots(self, repeat: int = 1) -> np.ndarray:
        """(n_slots,) True for the slots whose fish is on the line; with ``repeat``, each of them that many times
        (per body, per joint of the system).  Read-only, kept until a fish comes, goes or the system is rebuilt."""
        if (on := self._on_line.get(repeat)) is None:
            on = self.status[self.member] == ON_LINE
            on = on if repeat == 1 else np.repeat(on, repeat)
            on.setflags(write=False)
            self._on_line[repeat] = on
        return on

    def released(self, k: int, raised_by_m: float) -> None:
        """Fish ``k`` is on the line, dropped ``raised_by_m`` higher than asked (to clear the fish below it)."""
        if raised_by_m > 0:
            self.drop_adjustments += (DropAdjustment(self.fish_ids[k], raised_by_m),)
        self.status[k] = ON_LINE
        self._next_drop_t_s = None
        self._on_line.clear()

    def leaving(self, pos: np.ndarray, line: Line, retire_after_m: float, taken: np.ndarray) -> np.ndarray:
        """The slots whose fish is to be retired: on the line and past its end (every body ``retire_after_m`` beyond
        it), fallen off its end, or taken by a device (``taken``: per slot, the device's index, -1 for none);
        ``pos`` (n_slots, bodies per fish, 3) the bodies' centres."""
        x_gone = line.x_end_m + retire_after_m
        z_floor = line.z_range_m[0] - 0.5
        past = np.all(pos[:, :, 0] > x_gone, axis=1)
        fell_off_end = np.all(pos[:, :, 0] > line.x_end_m, axis=1) & np.all(pos[:, :, 2] < z_floor, axis=1)
        # one that left slowly drops beside the end drum, some of it not past the end: gone once far below
        fell_off_end |= (np.max(pos[:, :, 0], axis=1) > line.x_end_m - 0.1) & np.all(pos[:, :, 2] < z_floor - 0.5,
                                                                                 axis=1)
        return np.flatnonzero(self.on_line_slots() & (past | fell_off_end | (taken >= 0)))

    def retired(self, slot: int, taken_by: int) -> None:
        """The fish of ``slot`` has left the line: rejected by device ``taken_by``, or (-1) gone past its end."""
        k = self.member[slot]
        self.status[k], self.rejected_by[k] = (REJECTED, taken_by) if taken_by >= 0 else (LEFT, -1)
        self._on_line.clear()

    def rebuild_due(self) -> bool:
        """A quarter of the fish in the system (two at least) are gone: rebuilt without them it steps faster."""
        return self._gone() >= self._gone_for_rebuild()

    def _gone(self) -> int:
        return int(np.sum(self.status[self.member] >= LEFT))

    def _gone_for_rebuild(self) -> int:
        return max(2, len(self.member) // 4)
