"""The ``fishfmu`` command: parses arguments and calls functions that a script can call too.

Exit codes: 0 ok, 1 an ``[expect]`` bound failed, 2 bad input, 3 the simulation or an FMU failed.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer
from rich.console import Console

from plant.errors import EXIT_BAD_INPUT, EXIT_EXPECT_FAILED, EXIT_SIMULATION_FAILED, InputError, SimulationError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Co-simulate salmon singulation lines: plant in Exudyn, drives and controller as FMUs.")
err_console = Console(stderr=True)


@app.callback()
def _root() -> None:
    """Co-simulate salmon singulation lines."""


@app.command("build-fmus")
def build_fmus(
    names: list[str] = typer.Argument(None, help="FMUs to build (default: all built-in ones)."),
    out: Path = typer.Option(..., "--out", help="Folder for the .fmu files."),
    param: list[str] = typer.Option([], "--param", help="Bake in a parameter default: --param gear_ratio=8 "
                                                         "(repeatable; needs a single FMU name)."),
) -> None:
    """Build the built-in FMUs as standalone .fmu files (Linux binary and C sources inside)."""
    from fishfmu.fmu_build import BUILTIN_FMUS, FmuBuildError, build_fmu
    from fishfmu.scenario import parse_value
    defaults = {}
    for item in param:
        key, eq, value = item.partition("=")
        if not eq:
            raise InputError(f"--param '{item}': expected NAME=VALUE")
        defaults[key.strip()] = parse_value(value.strip())
    if defaults and len(names or BUILTIN_FMUS) != 1:
        raise InputError("--param needs exactly one FMU name (parameters differ between FMUs)")
    for name in names or BUILTIN_FMUS:
        try:
            print(build_fmu(name, out, defaults))
        except FmuBuildError as exc:
            err_console.print(f"[bold red]build failed:[/] {name}: {exc}", highlight=False)
            raise typer.Exit(EXIT_SIMULATION_FAILED) from exc


def _show_progress() -> bool:
    return sys.stderr.isatty() and not os.environ.get("CI")


def print_kpis(result, console: Console) -> None:
    """The KPIs as a table, then each [expect] bound with its outcome."""
    from rich.table import Table
    table = Table(title=f"KPIs: {result.scenario.run.name} (seed {result.scenario.run.seed})")
    table.add_column("KPI")
    table.add_column("value", justify="right")
    for key in ("fish_in", "throughput_time_s", "fpm_in", "singulated", "singulation_rate", "fpm_out", "lost",
                "gap_min_m", "gap_p10_m", "gap_median_m", "method"):
        if key in result.kpis:
            v = result.kpis[key]
            table.add_row(key, f"{v:.3f}" if isinstance(v, float) else str(v))
    console.print(table)
    for e in result.expect:
        console.print(("[green]ok[/]   " if e.ok else "[red]FAIL[/] ") + e.message, highlight=False)


@app.command("run")
def run(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML)."),
    out: Path | None = typer.Option(None, "--out", help="Output folder (default: out/<scenario name>)."),
    junit: Path | None = typer.Option(None, "--junit", help="Write each [expect] bound as a JUnit test case here."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value: --set fish.count=30 (repeatable)."),
    seed: int | None = typer.Option(None, "--seed", help="Override run.seed."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier run in --out."),
    report: bool = typer.Option(True, "--report/--no-report", help="Write the HTML/PNG report."),
    replay: bool = typer.Option(False, "--replay", help="Also write replay.html: the run in 3D in a browser."),
) -> None:
    """Run a scenario: KPIs as a table; exit 0 ok, 1 an [expect] bound failed, 2 bad input, 3 run failed."""
    from fishfmu.outputs import prepare_out_dir, write_junit, write_outputs
    from fishfmu.runner import run_scenario
    from fishfmu.scenario import load_scenario, parse_value

    overrides = {}
    for item in set_:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise InputError(f"--set '{item}': expected KEY=VALUE")
        overrides[key.strip()] = parse_value(value.strip())
    if seed is not None:
        overrides["run.seed"] = seed
    sc = load_scenario(scenario, overrides)
    out_dir = prepare_out_dir(out if out is not None else Path("out") / scenario.stem, overwrite or out is None)
    console = Console()
    if _show_progress():
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[t]:.1f} s simulated"),
                      TimeElapsedColumn(), console=Console(stderr=True), transient=True) as bar:
            task = bar.add_task(sc.run.name, total=sc.run.duration_s, t=0.0)
            result = run_scenario(sc, scenario, record_poses=replay,
                                  on_progress=lambda t, total: bar.update(task, completed=t, total=total, t=t))
    else:
        result = run_scenario(sc, scenario, record_poses=replay)
    write_outputs(result, out_dir, report=report)
    if replay:
        from fishfmu.replay import write_replay
        console.print(f"replay: {write_replay(out_dir)}", highlight=False)
    if junit is not None:
        write_junit(result, junit, str(scenario))
    print_kpis(result, console)
    console.print(f"outputs: {out_dir}", highlight=False)
    if result.status != "ok":
        raise SimulationError(f"{result.error} (results so far written to {out_dir})")
    if not result.expect_ok:
        raise typer.Exit(EXIT_EXPECT_FAILED)


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
