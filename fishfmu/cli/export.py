"""The commands that write FMUs and SSP archives for other tools: ``build-fmus``, ``export-fmu``, ``export-ssp``.

Registered on the ``fishfmu`` app by :mod:`fishfmu.cli`; like every command they parse and call
:mod:`fishfmu.commands`, importing it inside the function so that ``--help`` answers at once.
"""

from __future__ import annotations

from pathlib import Path

import typer

from fishfmu.scenario.keys import parse_assignments
from fishfmu.terminal import console as literal_console


def build_fmus(
    names: list[str] = typer.Argument(None, help="FMUs to build (default: all built-in ones)."),
    out: Path = typer.Option(..., "--out", help="Folder for the .fmu files."),
    param: list[str] = typer.Option([], "--param", help="Bake in a parameter default: --param gear_ratio=8 "
                                                         "(repeatable; needs a single FMU name)."),
) -> None:
    """Build the built-in FMUs as standalone .fmu files (Linux binary and C sources inside)."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    for path in commands.build_fmus(names or [], out, parse_assignments(param, "--param")):  # a failure: exit 3
        print(path)


def export_fmu_cmd(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML): its line, fish, plant and kpi tables."),
    out: Path = typer.Option(..., "--out", help="The .fmu to write (replaced only if fishfmu wrote it)."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value (repeatable)."),
) -> None:
    """The plant (line, fish, drops, extensions) as an FMI 2.0 co-simulation FMU for other masters; it needs Python
    with fishfmu installed on the host (made with pythonfmu)."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    path = commands.export_fmu(scenario, out, parse_assignments(set_))
    literal_console().print(f"written: {path}")


def export_ssp_cmd(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML)."),
    out: Path = typer.Option(..., "--out", help="The .ssp to write (replaced only if fishfmu wrote it)."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value (repeatable)."),
) -> None:
    """The scenario's system as an SSP 1.0 archive for other tools: every FMU and the plant (as export-fmu makes it)
    as components, the connections with gain and offset, the parameter values as SSV; prints what SSP cannot say
    (events, [expect], [record], ...), which the archive lists too."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    path, notes = commands.export_ssp(scenario, out, parse_assignments(set_))
    console = literal_console()
    console.print(f"written: {path}\nnot in the SSP (listed in resources/fishfmu-not-in-ssp.txt of the archive):")
    for note in notes:
        console.print(f"  - {note}")
