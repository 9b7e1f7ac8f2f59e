"""What a run loop polls to stop between two steps.

A :class:`StopRequest` is set by a signal (SIGINT, SIGTERM) and read by the loop that steps a run
(:func:`fishfmu.cosim.runner.run_scenario`, the served line): it ends after the current communication
step, and the command writes what was recorded, marked ``"status": "partial"``.  The signals themselves
are answered in one place, :mod:`fishfmu.session` (:func:`fishfmu.session.stop_between_steps` gives the
request a run polls); this module only holds the request, so that the co-simulation does not depend on how
a command handles its process.
"""

from __future__ import annotations

import signal


def exit_status(signum: int) -> int:
    """How a shell reports a process ended by the signal ``signum``: 128 + its number (130 for SIGINT, 143 for
    SIGTERM).  A command stopped by a signal exits with it, its partial results written."""
    return 128 + signum


class StopRequest:
    """Set by a signal; polled by the run loop."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    @property
    def exit_code(self) -> int:
        """The exit status of a command this signal stopped (:func:`exit_status`)."""
        return exit_status(self.signum or 0)
