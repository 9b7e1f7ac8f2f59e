"""The ``fishfmu`` command: parses arguments and calls functions that a script can call too.

Exit codes: 0 ok, 1 an ``[expect]`` bound failed, 2 bad input, 3 the simulation or an FMU failed,
4 an internal error (a bug), 130/143 a run stopped by SIGINT/SIGTERM (partial results written).
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import typer
from rich.console import Console

from plant.errors import (EXIT_BAD_INPUT, EXIT_EXPECT_FAILED, EXIT_INTERNAL_ERROR, EXIT_SIMULATION_FAILED, InputError,
                          SimulationError)

from fishfmu.terminal import console as literal_console, labelled, outcome, print_error

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None,  # help text is literal: "[expect]" stays in it
                  help="Co-simulate salmon singulation lines: plant in Exudyn, drives and controller as FMUs.")
err_console = literal_console(stderr=True)


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
    from fishfmu.fmu.build import BUILTIN_FMUS, FmuBuildError, build_fmu
    from fishfmu.scenario.schema import parse_assignments
    defaults = parse_assignments(param, "--param")
    if defaults and len(names or BUILTIN_FMUS) != 1:
        raise InputError("--param needs exactly one FMU name (parameters differ between FMUs)")
    from fishfmu.output.ownership import check_single_file_target, record_written
    for name in names or BUILTIN_FMUS:  # an existing .fmu is replaced only if fishfmu wrote it
        check_single_file_target(out / f"{name}.fmu")
    for name in names or BUILTIN_FMUS:
        try:
            fmu_path = build_fmu(name, out, defaults)
            record_written(fmu_path)
            print(fmu_path)
        except FmuBuildError as exc:
            print_error("build failed", f"{name}: {exc}")
            raise typer.Exit(EXIT_SIMULATION_FAILED) from exc


def _run_inputs(scenario: Path, sc, junit: Path | None) -> list:
    """The files a run reads (never written over); checks ``--junit`` against them and for ownership."""
    from fishfmu.output.ownership import check_single_file_target
    inputs = [scenario, *(f.path for f in sc.fmu if f.path)]
    if junit is not None:
        check_single_file_target(junit, inputs)
    return inputs


def _show_progress() -> bool:
    return sys.stderr.isatty() and not os.environ.get("CI")


def print_kpis(result, console: Console) -> None:
    """The KPIs as a table, then each [expect] bound with its outcome."""
    from rich.table import Table
    table = Table(title=f"KPIs: {result.scenario.run.name} (seed {result.scenario.run.seed})")
    table.add_column("KPI")
    table.add_column("value", justify="right")
    from plant.kpis import SHOWN_KPI_KEYS
    for key in (*SHOWN_KPI_KEYS, "method"):
        if key in result.kpis:
            v = result.kpis[key]
            table.add_row(key, f"{v:.3f}" if isinstance(v, float) else str(v))
    console.print(table)
    for e in result.expect:
        console.print(outcome(e.ok, e.message))


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
    seeds: int = typer.Option(1, "--seeds", min=1, help="Run this many seeds (run.seed and the ones after it) on "
                                                          "Dask; KPIs as mean and 95 % CI, [expect] on the means."),
    workers: int | None = typer.Option(None, "--workers", help="With --seeds: local worker processes (default: cores)."),
    scheduler: str | None = typer.Option(None, "--scheduler", help="With --seeds: address of a running Dask scheduler."),
) -> None:
    """Run a scenario: KPIs as a table; exit 0 ok, 1 an [expect] bound failed, 2 bad input, 3 run failed."""
    from fishfmu.cosim.interrupt import register_output, stop_on_signals
    from fishfmu.output.run_folder import (discard_if_unused, junit_args_of_run, mark_running, prepare_out_dir, write_junit,
                                 write_outputs)
    from fishfmu.cosim.runner import check_scenario, run_scenario
    from fishfmu.scenario.schema import load_scenario, parse_assignments

    overrides = parse_assignments(set_)
    if seed is not None:
        overrides["run.seed"] = seed
    if seeds > 1:  # Monte-Carlo over seeds: fishfmu.batch.seeds
        if replay:
            raise InputError("--replay shows one run; drop it or run without --seeds")
        from fishfmu.batch.seeds import run_seeds_command
        from fishfmu.batch.sweep import check_size
        check_size(1, seeds)  # before anything is written
        sc = load_scenario(scenario, overrides)
        check_scenario(sc, scenario)
        out_dir = prepare_out_dir(out if out is not None else Path("out") / scenario.stem, overwrite,
                                  _run_inputs(scenario, sc, junit), "run")
        register_output(out_dir, {"command": "run", "seeds": seeds})  # a signal: run_info.json says partial
        raise typer.Exit(run_seeds_command(scenario, overrides, seeds, out_dir, junit, scheduler, workers,
                                           _show_progress()))
    sc = load_scenario(scenario, overrides)
    check_scenario(sc, scenario)  # FMU files, parameters, wiring: bad input before anything is written
    out_dir = prepare_out_dir(out if out is not None else Path("out") / scenario.stem, overwrite,
                              _run_inputs(scenario, sc, junit), "run")
    mark_running(out_dir, scenario)
    register_output(out_dir)
    console = literal_console()
    with stop_on_signals() as stop:  # Ctrl-C / SIGTERM: stop after this step, write what there is
        try:
            if _show_progress():
                from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
                with Progress(TextColumn("{task.description}"), BarColumn(),
                              TextColumn("{task.fields[t]:.1f} s simulated"), TimeElapsedColumn(),
                              console=literal_console(stderr=True), transient=True) as bar:
                    task = bar.add_task(sc.run.name, total=sc.run.duration_s, t=0.0)
                    result = run_scenario(sc, scenario, record_poses=replay, stop=stop,
                                          on_progress=lambda t, total: bar.update(task, completed=t, total=total, t=t))
            else:
                result = run_scenario(sc, scenario, record_poses=replay, stop=stop)
        except InputError:
            discard_if_unused(out_dir)
            raise
        write_outputs(result, out_dir, report=report)
    if replay:
        from fishfmu.output.replay import write_replay
        console.print(f"replay: {write_replay(out_dir)}")
    if junit is not None:
        write_junit(junit, **junit_args_of_run(result, str(scenario)))
    print_kpis(result, console)
    console.print(f"outputs: {out_dir}")
    if result.status == "partial":
        err_console.print(labelled("stopped:", f"{result.error}; partial results written to {out_dir}", "bold yellow"))
        raise typer.Exit(stop.exit_code)
    if result.status != "ok":
        raise SimulationError(f"{result.error} (results so far written to {out_dir})")
    if not result.expect_ok:
        raise typer.Exit(EXIT_EXPECT_FAILED)


@app.command("sweep")
def sweep(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML)."),
    param: list[str] = typer.Option([], "--param", help="Swept key and values: --param fish.length_mean_m=0.5,0.6 "
                                                         "or KEY=START:STOP:N (repeatable; every combination runs)."),
    seeds: int = typer.Option(5, "--seeds", min=1, help="Fish batches per point: run.seed and the N-1 after it."),
    out: Path = typer.Option(..., "--out", help="Sweep folder; the same command on the same folder resumes."),
    set_: list[str] = typer.Option([], "--set", help="Fixed override at every point: --set fish.count=30."),
    scheduler: str | None = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler "
                                                                   "(default: a local cluster)."),
    workers: int | None = typer.Option(None, "--workers", help="Local worker processes (default: cores)."),
    threads_per_worker: int = typer.Option(1, "--threads-per-worker", min=1, help="Threads per local worker."),
    max_runs: int | None = typer.Option(None, "--max-runs", min=0, help="Stop after this many runs (resume later)."),
    retry_failed: bool = typer.Option(False, "--retry-failed", help="Re-run failed runs when resuming."),
) -> None:
    """Sweep parameters x seeds on Dask: runs/summary tables (parquet, CSV) and plots with 95 % CI bands."""
    from fishfmu.batch.sweep import make_spec, parse_param, run_sweep
    from fishfmu.batch.sweep_report import print_summary
    from fishfmu.scenario.schema import parse_assignments
    fixed = parse_assignments(set_)
    params = dict(parse_param(p) for p in param)
    if len(params) != len(param):
        raise InputError("a key is given twice with --param")
    spec = make_spec(scenario, params, seeds, fixed)
    from fishfmu.cosim.interrupt import register_output
    register_output(out, {"command": "sweep"})
    result = run_sweep(spec, out, scheduler=scheduler, workers=workers, threads_per_worker=threads_per_worker,
                       progress=_show_progress(), max_runs=max_runs, retry_failed=retry_failed)
    console = literal_console()
    if len(result.summary):
        print_summary(result.summary, list(spec.parameters), console, title=scenario.stem)
    done = len(result.runs)
    console.print(f"{done} of {result.n_runs} runs done ({result.n_executed} now, {result.n_skipped} from before), "
                  f"{int((result.runs['status'] != 'ok').sum()) if done else 0} failed, {result.wall_s:.0f} s; "
                  f"tables and plots in {result.out}")
    if result.interrupted:
        console.print(labelled("stopped:", f"by {signal.Signals(result.exit_code_interrupted - 128).name}; run the "
                               "same command again to resume", "yellow"))
        raise typer.Exit(result.exit_code_interrupted)


@app.command("bench")
def bench(
    fish: str = typer.Option("18,50,100,200", "--fish", help="Fish counts, comma separated."),
    duration: float = typer.Option(5.0, "--duration", help="Simulated seconds measured after the drop."),
    comm_step: float = typer.Option(0.01, "--comm-step", help="Communication step [s]."),
    threads: int = typer.Option(1, "--threads", help="Exudyn threads."),
    json_file: Path | None = typer.Option(None, "--json", help="Write the records as a JSON list here."),
    plot_file: Path | None = typer.Option(None, "--plot", help="Write a PNG of cost against fish count here."),
) -> None:
    """Real-time factor of plant and co-simulation for several fish counts, where time goes, peak memory."""
    import json

    from rich.table import Table

    from fishfmu.bench.pile import per_fish_cost, plot, records_json, run_bench
    try:
        counts = [int(x) for x in fish.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--fish '{fish}': expected comma-separated integers") from None
    if not counts or min(counts) < 0:
        raise InputError(f"--fish '{fish}': give one or more fish counts >= 0")
    console = literal_console()
    table = Table(title=f"fishfmu bench: {duration:g} s simulated after the drop, step {comm_step:g} s, {threads} thread(s)")
    for col in ("fish", "RTF plant", "RTF co-sim", "Exudyn", "plant py", "FMUs", "master", "recording",
                "FMU+master+rec", "peak MB"):
        table.add_column(col, justify="right")

    def row(r) -> None:
        w = r.wall_cosim_s
        table.add_row(str(r.fish), f"{r.rtf_plant:.2f}", f"{r.rtf_cosim:.2f}", f"{100 * r.plant_exudyn_s / w:.0f} %",
                      f"{100 * r.plant_python_s / w:.0f} %", f"{100 * r.fmu_s / w:.1f} %", f"{100 * r.master_s / w:.1f} %",
                      f"{100 * r.recording_s / w:.1f} %", f"{100 * r.overhead_fraction:.1f} %", f"{r.peak_rss_mb:.0f}")
        err_console.print(f"measured {r.fish} fish: RTF plant {r.rtf_plant:.2f}, co-sim {r.rtf_cosim:.2f}")

    from fishfmu.output.ownership import check_single_file_target, note_temp, replace_into
    for target in (json_file, plot_file):  # before measuring: an existing file is replaced only if ours
        if target is not None:
            check_single_file_target(target)
    records = run_bench(counts, duration, comm_step, threads, on_record=row)
    console.print(table)
    base, per = per_fish_cost(records)
    console.print(f"plant step cost: {base:.2f} ms with no fish + {per:.3f} ms per fish (straight line through the "
                  "measured counts)")
    if json_file is not None:
        from fishfmu.output.run_folder import write_text_atomic
        write_text_atomic(json_file, json.dumps(records_json(records), indent=2) + "\n")
    if plot_file is not None:
        tmp = plot_file.with_name(f".{plot_file.name}.part{plot_file.suffix}")
        note_temp(tmp)
        plot(records, tmp)
        replace_into(tmp, plot_file)


@app.command("replay")
def replay_cmd(
    run_dir: Path = typer.Argument(..., help="Output folder of a `fishfmu run --replay`."),
    out: Path | None = typer.Option(None, "--out", help="HTML file to write (default: RUN_DIR/replay.html)."),
) -> None:
    """Write a run as one HTML page that replays it in 3D in a browser (offline, from the file)."""
    from fishfmu.output.ownership import check_single_file_target
    from fishfmu.output.replay import write_replay
    check_single_file_target(out if out is not None else run_dir / "replay.html",
                             [run_dir / "run", run_dir / "poses.npz", run_dir / "scenario.resolved.toml"])
    print(write_replay(run_dir, out))


def _dataset_and_params(dataset: Path, scenario: Path | None):
    from plant.measured import read_dataset
    from plant.params import PlantParams
    ds = read_dataset(dataset)
    if scenario is None:
        return ds, PlantParams(), None
    from fishfmu.scenario.schema import load_scenario
    sc = load_scenario(scenario)
    drives = [f.parameters for f in sc.fmu if f.builtin == "conveyor_drive"]
    return ds, sc.plant, (drives[0] if drives else None)


@app.command("compare")
def compare(
    dataset: Path = typer.Argument(..., help="Measured dataset folder (contracts/measured-data.md)."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    scenario: Path | None = typer.Option(None, "--scenario", help="Take plant parameters (and drive parameters) "
                                                                 "from this scenario instead of the defaults."),
    workers: int | None = typer.Option(None, "--workers", help="Parallel processes (default: all cores)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier result in --out."),
) -> None:
    """Re-simulate every measured run and show what the simulation gets wrong (KPIs, arrivals, tracks, belts)."""
    from fishfmu.analysis.compare import compare_dataset, write_comparison
    from fishfmu.output.run_folder import prepare_out_dir, write_run_info
    ds, params, drive = _dataset_and_params(dataset, scenario)
    out_dir = prepare_out_dir(out, overwrite, [dataset, scenario], "compare")
    from fishfmu.cosim.interrupt import current, register_output
    register_output(out_dir, {"command": "compare", "dataset": str(dataset)})  # a signal: run_info.json says partial
    c = compare_dataset(ds, params, workers, drive)  # a signal: the runs re-simulated by then are compared
    paths = write_comparison(c, out_dir)
    stopped = current() is not None and current().requested
    failure = None if stopped else c.failure()  # a re-simulation that failed: exit 3 once the rest is written
    write_run_info(out_dir, "partial" if stopped else "failed" if failure else "ok", command="compare",
                   dataset=str(dataset), **({"stopped_by": current().signal_name} if stopped else {}),
                   **({"error": failure} if failure else {}))
    from rich.table import Table
    table = Table(title=f"{ds.name}: simulated - measured, over {len(ds.runs)} runs")
    for col in ("measure", "mean", "sd", "min", "max"):
        table.add_column(col, justify="right" if col != "measure" else "left")
    for row in c.summary().itertuples():
        table.add_row(row.measure, *[f"{getattr(row, k):.4g}" for k in ("mean", "sd", "min", "max")])
    literal_console().print(table)
    literal_console().print(f"report: {paths['report']}")
    if stopped:
        err_console.print(labelled("stopped:", f"by {current().signal_name}; runs not re-simulated are listed as "
                                   f"failed in {out_dir / 'compare.json'}", "bold yellow"))
        raise typer.Exit(current().exit_code)
    if failure:
        raise SimulationError(f"{failure} (what the other runs gave is written to {out_dir})")


@app.command("diagnose")
def diagnose_cmd(
    dataset: Path = typer.Argument(..., help="Measured dataset folder (contracts/measured-data.md)."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    scenario: Path | None = typer.Option(None, "--scenario", help="Start from this scenario's plant parameters."),
    workers: int | None = typer.Option(None, "--workers", help="Parallel processes (default: all cores)."),
    max_fit: int = typer.Option(3, "--max-fit", help="Fit at most this many plant candidates by simulation."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier result in --out."),
) -> None:
    """Name the cause of what the simulation gets wrong, fit it, and measure the gain on held-out runs."""
    from fishfmu.analysis.diagnose import diagnose
    from fishfmu.analysis.diagnose_report import decision_text, write_diagnosis
    from fishfmu.output.run_folder import prepare_out_dir, write_run_info
    ds, params, _ = _dataset_and_params(dataset, scenario)
    out_dir = prepare_out_dir(out, overwrite, [dataset, scenario], "diagnose")
    from fishfmu.cosim.interrupt import register_output
    register_output(out_dir, {"command": "diagnose", "dataset": str(dataset)})  # a signal: run_info.json says partial
    try:
        d = diagnose(ds, params, workers, max_fit, progress=lambda text: err_console.print(text))
    except SimulationError as exc:  # a run the model cannot re-simulate: exit 3, run_info.json says why
        write_run_info(out_dir, "failed", command="diagnose", dataset=str(dataset), error=str(exc))
        raise
    paths = write_diagnosis(d, out_dir)
    write_run_info(out_dir, "ok", command="diagnose", dataset=str(dataset))
    literal_console().print(labelled("cause:", d.cause, "bold"))
    literal_console().print(decision_text(d))
    literal_console().print(f"diagnosis: {paths['json']}\nfragment: {paths['fragment']}\nreport: {paths['report']}")


def main() -> None:
    """Entry point: turn our own errors into one clear line and the matching exit code."""
    from fishfmu.cosim.interrupt import Interrupted, mark_partial, session
    try:
        code = 0
        with session() as s:  # SIGINT/SIGTERM: workers stopped, temporary folder removed, exit 130/143
            try:
                app(standalone_mode=True)
            except Interrupted as exc:
                mark_partial(s.out_dir, exc.signum, s.out_info)
                where = f"; what finished is in {s.out_dir} (run_info.json: partial)" if s.out_dir is not None else ""
                err_console.print(labelled("stopped:", f"by {exc.signal_name}{where}", "bold yellow"))
                code = exc.exit_code
        sys.exit(code)
    except InputError as exc:
        print_error("error", exc)
        sys.exit(EXIT_BAD_INPUT)
    except SimulationError as exc:
        print_error("simulation failed", exc)
        sys.exit(EXIT_SIMULATION_FAILED)
    except OSError as exc:  # an output location that cannot be written (disk full, read-only): not a bug
        from fishfmu.output.ownership import os_error
        print_error("error", os_error(exc, exc.filename or "output", "cannot write" if exc.filename else "I/O error"))
        sys.exit(EXIT_BAD_INPUT)
    except RuntimeError as exc:  # Path.resolve() on a symbolic link loop (Python < 3.13): bad input, not a bug
        if not str(exc).startswith("Symlink loop from "):
            _internal_error(exc)
        print_error("error", f"{str(exc).removeprefix('Symlink loop from ').strip(chr(39))}: a symbolic link loop "
                             "(the path leads back to itself)")
        sys.exit(EXIT_BAD_INPUT)
    except Exception as exc:  # a bug: say so in one line, with where it happened (traceback on request)
        _internal_error(exc)


def _internal_error(exc: Exception) -> None:
    """A bug: one line saying where it happened (the traceback with FISHFMU_DEBUG=1); exit 4."""
    if os.environ.get("FISHFMU_DEBUG"):
        raise exc
    import traceback
    frame = traceback.extract_tb(exc.__traceback__)[-1]
    err_console.print(labelled("internal error", "(a bug in fishfmu; please report it, FISHFMU_DEBUG=1 shows "
                               f"the traceback): {type(exc).__name__}: {exc} "
                               f"[{Path(frame.filename).name}:{frame.lineno}]", "bold red"))
    sys.exit(EXIT_INTERNAL_ERROR)


if __name__ == "__main__":
    main()
