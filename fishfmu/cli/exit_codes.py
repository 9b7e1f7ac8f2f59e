"""The exit codes of the ``fishfmu`` command: the one place they are defined.

Code below the command line reports what happened as exceptions (:mod:`plant.errors`: ``InputError`` is
exit 2, ``SimulationError`` and ``SystemDependencyError`` exit 3, anything else a bug, exit 4) or as results
(a run's status, ``[expect]`` outcomes, a stop by a signal); only the command line turns them into a
process's exit code: ``fishfmu.cli.main`` catches each exception, :func:`for_seeds` judges ``run --seeds``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # a type only: the seeds' results are passed in, never made here
    from fishfmu.batch.seeds import SeedsResult

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
        return result.sweep.exit_code_interrupted  # 130 / 143: partial results
    if result.n_failed:
        return EXIT_SIMULATION_FAILED
    return EXIT_OK if all(e.ok for e in result.expect) else EXIT_EXPECT_FAILED
