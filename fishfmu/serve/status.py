"""The served run's state and its clock against the wall, as a PLC sees them (``fishfmu.run_state`` and the
status variables beside it).

States: ``waiting`` (``--wait-for-start``: built, not yet started by a client's ``start()``), ``running``,
``paused`` (a client's ``pause()``, until ``resume()``), ``finished`` (the scenario's end), ``stopped`` (a client's
``stop()`` or a signal), ``failed: <why>`` (an FMU or the plant failed).  Every change of state is announced as an
OPC UA event from the root object.

The clock: ``lag_s`` is how late the last step started against its due time on the wall clock (real time; 0 in
lockstep), ``lag_max_s`` the largest since the run (re)started, ``late_steps`` the steps that started more than one
communication step (of wall time) late, ``realtime_factor_reached`` the simulated time per second of wall time
while running (paused and waiting time left out).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

WAITING, RUNNING, PAUSED, FINISHED, STOPPED = "waiting", "running", "paused", "finished", "stopped"
FAILED = "failed"
"""A failure is ``failed: <why>``."""
DEFAULT_GRACE_S = 60.0
"""How long the server stays up after the run finished or failed, for a PLC to read that and the KPIs, unless a
client calls stop() first."""
GRACE_RANGE_S = (0.0, 86400.0)


def has_ended_by_itself(state: str) -> bool:
    """The run reached its end or failed (not a client's stop): the server lingers for the grace time."""
    return state == FINISHED or state.startswith(FAILED)


def grace_problem(grace_s: float) -> str | None:
    lo, hi = GRACE_RANGE_S
    if lo <= grace_s <= hi:
        return None
    return f"{grace_s:g} s is not a grace time in [{lo:g}, {hi:g}] s"


@dataclass
class RunClock:
    """Wall time spent running, to give the real-time factor reached (see the module docstring)."""

    running_wall_s: float = 0.0
    running_since: float | None = None
    ended_at: float | None = None
    """Monotonic time the run finished or failed (the grace time runs from it)."""

    def enter(self, state: str) -> None:
        """The run's state is now ``state``: count wall time while running, note when it ended by itself."""
        now = time.monotonic()
        if state == RUNNING and self.running_since is None:
            self.running_since = now
        elif state != RUNNING and self.running_since is not None:
            self.running_wall_s += now - self.running_since
            self.running_since = None
        self.ended_at = (self.ended_at or now) if has_ended_by_itself(state) else None

    def factor_reached(self, t_s: float) -> float:
        wall = self.running_wall_s + (time.monotonic() - self.running_since if self.running_since else 0.0)
        return t_s / wall if wall > 0 else 0.0

    def grace_over(self, grace_s: float) -> bool:
        return self.ended_at is not None and time.monotonic() - self.ended_at >= grace_s


class InvalidState(Exception):
    """A client asked what the run's state does not allow (start() while running, step() while paused)."""
