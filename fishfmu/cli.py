"""The ``fishfmu`` command: parses arguments and calls functions that a script can call too.

Exit codes: 0 ok, 1 an ``[expect]`` bound failed, 2 bad input, 3 the simulation or an FMU failed.
"""

from __future__ import annotations

import sys

import typer
from rich.console import Console

from plant.errors import EXIT_BAD_INPUT, EXIT_SIMULATION_FAILED, InputError, SimulationError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Co-simulate salmon singulation lines: plant in Exudyn, drives and controller as FMUs.")
err_console = Console(stderr=True)


@app.callback()
def _root() -> None:
    """Co-simulate salmon singulation lines."""


def main() -> None:
    """Entry point: turn our own errors into one clear line and the matching exit code."""
    try:
        app(standalone_mode=True)
    except InputError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False)
        sys.exit(EXIT_BAD_INPUT)
    except SimulationError as exc:
        err_console.print(f"[bold red]simulation failed:[/] {exc}", highlight=False)
        sys.exit(EXIT_SIMULATION_FAILED)


if __name__ == "__main__":
    main()
