"""Stopping a run cleanly on Ctrl-C (SIGINT) or SIGTERM.

Inside :func:`stop_on_signals` the first SIGINT or SIGTERM only sets a flag; the run loop
(:func:`fishfmu.cosim.runner.run_scenario`) sees it at the end of the current communication step, stops,
and the command writes what was recorded so far, marked ``"status": "partial"``, and exits with
128 + the signal number (130 for SIGINT, 143 for SIGTERM), the shell's convention.  A second
signal is not waited on: the previous handler is put back and the signal delivered again (Ctrl-C
twice stops at once; files are written atomically, so none is left half-written under its name).

Commands with worker processes stop through :mod:`fishfmu.session` instead.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


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
        """128 + the signal number, as a shell reports a process ended by that signal."""
        return 128 + (self.signum or 0)


@contextmanager
def stop_on_signals(signals: tuple[int, ...] = SIGNALS) -> Iterator[StopRequest]:
    """Turn the first of ``signals`` into a stop request for the duration of the block."""
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request  # signal handlers can only be set from the main thread
        return
    previous = {s: signal.getsignal(s) for s in signals}

    def handler(signum: int, _frame) -> None:  # noqa: ANN001
        if request.signum is None:
            request.signum = signum
            return
        for s, h in previous.items():  # second signal: the old behaviour, now
            signal.signal(s, h)
        os.kill(os.getpid(), signum)

    for s in signals:
        signal.signal(s, handler)
    try:
        yield request
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
