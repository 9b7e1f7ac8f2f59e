"""The exit codes of the ``fishfmu`` command: the one place they are defined.

Code below the command line reports what happened as exceptions (:mod:`plant.errors`: ``InputError`` is
exit 2, ``SimulationError`` and ``SystemDependencyError`` exit 3, anything else a bug, exit 4) or as results
(a run's status, ``[expect]`` outcomes, a stop by a signal); only the command line turns them into a
process's exit code: :func:`for_error` maps each exception ``fishfmu.cli.main`` catches, :func:`for_run` judges a
run or a served run, :func:`for_seeds` ``run --seeds``.  A command a signal stopped exits with the signal's
status (128 + its number: :func:`fishfmu.cosim.stop.exit_status`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from plant.errors import InputError, SimulationError, SystemDependencyError

from fishfmu.cosim.stop import exit_status
from fishfmu.output.manifest_state import os_error

if TYPE_CHECKING:  # types only: the results are passed in, never made here
    from fishfmu.batch.seeds import SeedsResult
    from fishfmu.cosim.results import RunResult

EXIT_OK = 0
EXIT_EXPECT_FAILED = 1
"""The run finished, an ``[expect]`` bound did not hold."""
EXIT_BAD_INPUT = 2
"""What the user gave is wrong (a file, a key, a row, an option): one line naming where, nothing run."""
EXIT_SIMULATION_FAILED = 3
"""The run could not go on (a blow-up, an FMU that failed), or could not be made: the machine lacks a system
package fishfmu needs (nothing the user gave is wrong, and changing it will not help)."""
EXIT_INTERNAL_ERROR = 4
"""Anything else: a bug in fishfmu, reported in one line (``FISHFMU_DEBUG=1`` shows the traceback)."""
EXIT_INTERRUPTED_SIGINT = 130
EXIT_INTERRUPTED_SIGTERM = 143
"""A run stopped by Ctrl-C / SIGTERM (128 + signal number), its partial results written."""


def for_seeds(result: SeedsResult) -> int:
    """``run --seeds``: the signal's code if one stopped it (partial results), 3 if a run failed, else 1 if a
    bound on the means did not hold, else 0."""
    if result.sweep.interrupted:
        return for_signal(result.sweep.stop_signal)  # 130 / 143: partial results
    if result.n_failed:
        return EXIT_SIMULATION_FAILED
    return EXIT_OK if all(e.ok for e in result.expect) else EXIT_EXPECT_FAILED


def for_signal(signum: int) -> int:
    """A command a signal stopped (``sweep``, ``run --seeds``: what finished is written): 130 for SIGINT, 143 for
    SIGTERM (:func:`fishfmu.cosim.stop.exit_status`)."""
    return exit_status(signum)


def for_run(result: RunResult, stop_exit_code: int | None) -> int:
    """A run (``run``, ``serve``) written into its folder: the signal's code if one came (it stopped the run, partial
    results, or came while its whole results were written),
    3 if it failed, else 1 if an ``[expect]`` bound did not hold, else 0."""
    if result.status in ("partial", "ok") and stop_exit_code is not None:
        return stop_exit_code  # a signal came: it stopped the run, or came while its results were written
    if result.status != "ok":
        return EXIT_SIMULATION_FAILED
    return EXIT_OK if result.expect_ok else EXIT_EXPECT_FAILED


def for_error(exc: Exception) -> tuple[str, str, int] | None:
    """An exception that reached the command line as (the label of its one line, its message, the exit code);
    None for a bug (exit :data:`EXIT_INTERNAL_ERROR`, reported with where it happened)."""
    if isinstance(exc, InputError):  # an output location that cannot be written too (OutputError)
        return "error", str(exc), EXIT_BAD_INPUT
    if isinstance(exc, SimulationError):
        return "simulation failed", str(exc), EXIT_SIMULATION_FAILED
    if isinstance(exc, SystemDependencyError):  # the machine, not the user's files: the run cannot be made
        return "missing system package", str(exc), EXIT_SIMULATION_FAILED
    if isinstance(exc, OSError):  # an output location that cannot be written (disk full, read-only): not a bug
        return "error", str(os_error(exc, exc.filename or "output", "cannot write" if exc.filename else "I/O error")), \
            EXIT_BAD_INPUT
    if isinstance(exc, RuntimeError):
        # slow (fmpy and its CMake project, about 0.2 s) and needed only when a RuntimeError comes this far
        from fishfmu.fmu.compile import FmuBuildError
        if isinstance(exc, FmuBuildError):  # the compiler failed on a built-in FMU's sources (first use, any command)
            return "build failed", str(exc), EXIT_SIMULATION_FAILED
        if str(exc).startswith("Symlink loop from "):  # Path.resolve() on a link loop (Python < 3.13): bad input
            return "error", (f"{str(exc).removeprefix('Symlink loop from ').strip(chr(39))}: a symbolic link loop "
                             "(the path leads back to itself)"), EXIT_BAD_INPUT
    return None
