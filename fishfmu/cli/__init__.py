"""The ``fishfmu`` command: parses arguments and calls functions that a script can call too (:mod:`fishfmu.commands`).

Exit codes (:mod:`fishfmu.cli.exit_codes`): 0 ok, 1 an ``[expect]`` bound failed, 2 bad input, 3 the simulation or
an FMU failed (or the machine lacks a system package it needs), 4 an internal error (a bug), 130/143 a run stopped
by SIGINT/SIGTERM (partial results written).

Each command imports what it runs (:mod:`fishfmu.commands`, the scenario schema, the KPI keys: numpy, pandas,
pydantic, Exudyn, about 1.5 s) inside its function, each such import saying so: ``fishfmu --help``, a command's
help and a bad option answer at once without them.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import traceback
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from plant.errors import InputError, SimulationError

from fishfmu.cli import export, serving
from fishfmu.cli.bench import bench_app
from fishfmu.cli.exit_codes import EXIT_INTERNAL_ERROR, for_error, for_run, for_seeds, for_signal
from fishfmu.scenario.keys import parse_assignments
from fishfmu.session import Interrupted, session
from fishfmu.terminal import console as literal_console, labelled, outcome, print_error

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None,  # help text is literal: "[expect]" stays in it
                  help="Co-simulate salmon singulation lines: plant in Exudyn, drives and controller as FMUs.")
err_console = literal_console(stderr=True)


@app.callback()
def _root() -> None:
    """Co-simulate salmon singulation lines."""


app.add_typer(bench_app, name="bench")
app.command("build-fmus")(export.build_fmus)


def _show_progress() -> bool:
    return sys.stderr.isatty() and not os.environ.get("CI")


# ---------------------------------------------------------------- run

def print_kpis(result, console: Console) -> None:
    """The KPIs as a table, then each [expect] bound with its outcome."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from plant.contract.kpis import SHOWN_KPI_KEYS
    table = Table(title=f"KPIs: {result.scenario.run.name} (seed {result.scenario.run.seed})")
    table.add_column("KPI")
    table.add_column("value", justify="right")
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
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    overrides = parse_assignments(set_)
    if seed is not None:
        overrides["run.seed"] = seed
    if seeds > 1:
        if replay:
            raise InputError("--replay shows one run; drop it or run without --seeds")
        result, out_dir = commands.run_seeds(scenario, seeds, out, overrides, junit=junit, overwrite=overwrite,
                                             scheduler=scheduler, workers=workers, progress=_show_progress())
        _print_seeds(result, scenario, out_dir)
        raise typer.Exit(for_seeds(result))
    console = literal_console()
    if _show_progress():
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[t]:.1f} s simulated"),
                      TimeElapsedColumn(), console=literal_console(stderr=True), transient=True) as bar:
            task = bar.add_task(scenario.stem, total=None, t=0.0)
            done = commands.run(scenario, out, overrides, junit=junit, overwrite=overwrite, report=report,
                                replay=replay,
                                on_progress=lambda t, total: bar.update(task, completed=t, total=total, t=t))
    else:
        done = commands.run(scenario, out, overrides, junit=junit, overwrite=overwrite, report=report, replay=replay)
    result = done.result
    if done.replay is not None:
        console.print(f"replay: {done.replay}")
    _finish(result, done.out_dir, done.stop_exit_code, console)


def _finish(result, out_dir: Path, stop_exit_code: int | None, console) -> None:  # noqa: ANN001
    """A written run's KPIs and where it is; its exit: stopped by a signal, failed, an [expect] bound missed."""
    print_kpis(result, console)
    console.print(f"outputs: {out_dir}")
    if result.status == "partial":
        err_console.print(labelled("stopped:", f"{result.error}; partial results written to {out_dir}",
                                   "bold yellow"))
    elif result.status != "ok":
        raise SimulationError(f"{result.error} (results so far written to {out_dir})")
    elif stop_exit_code is not None:
        err_console.print(labelled("stopped:", f"by {signal.Signals(stop_exit_code - 128).name} after the run had "
                                   f"ended; its results were written whole to {out_dir} (run_info.json: ok)",
                                   "bold yellow"))
    raise typer.Exit(for_run(result, stop_exit_code))


@app.command("serve")
def serve_cmd(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML); [opcua] inputs names what clients write."),
    endpoint: str = typer.Option("opc.tcp://127.0.0.1:4840", "--endpoint", help="Where to listen (loopback only "
                                 "unless --allow-remote)."),
    realtime: float | None = typer.Option(None, "--realtime", help="Pace to the wall clock, times this factor "
                                          "(1 = real time; 0.001 to 1000); without it: lockstep, the line advances "
                                          "when a client calls step(n)."),
    lockstep: bool = typer.Option(False, "--lockstep", help="The line advances only when a client calls step(n) "
                                  "(the default; say it to be explicit)."),
    allow_remote: bool = typer.Option(False, "--allow-remote", help="Listen on a non-loopback address (unencrypted; "
                                      "with --user only that user may connect)."),
    user: str | None = typer.Option(None, "--user", help="Only this user may connect (password from the environment "
                                    "variable FISHFMU_OPCUA_PASSWORD); anonymous sessions are refused."),
    certificate: Path | None = typer.Option(None, "--certificate", help="The server's certificate (DER or PEM): "
                                            "only signed and encrypted policies are offered then."),
    private_key: Path | None = typer.Option(None, "--private-key", help="The server's private key (PEM)."),
    pki: Path | None = typer.Option(None, "--pki", help="Folder for the server's certificate (made on first use) and "
                                    "the trusted clients' (DIR/trusted), instead of --certificate etc."),
    trusted_clients: Path | None = typer.Option(None, "--trusted-clients", help="Folder of the client certificates "
                                                "that may connect (with --certificate)."),
    out: Path | None = typer.Option(None, "--out", help="Output folder (default: out/<scenario name>)."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value (repeatable)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier run in --out."),
    report: bool = typer.Option(True, "--report/--no-report", help="Write the HTML/PNG report."),
    wait_for_start: bool = typer.Option(False, "--wait-for-start", help="The line waits, in state 'waiting', until "
                                        "a client calls start()."),
    users: Path | None = typer.Option(None, "--users", help="TOML file of users with roles (operator: write, call; "
                                      "viewer: read) and `fishfmu hash-password` hashes."),
    allow_anonymous_write: bool = typer.Option(False, "--allow-anonymous-write", help="Lab bench: anonymous clients "
                                               "may write and call methods (by default they only read)."),
    modbus: str | None = typer.Option(None, "--modbus", help="HOST:PORT of a Modbus TCP server beside OPC UA (the "
                                      "register map: fishfmu signal-list)."),
    live: str | None = typer.Option(None, "--live", help="HOST:PORT of a web page that shows the running line in "
                                    "3D with its status (read-only; loopback only unless --allow-remote)."),
    grace: float | None = typer.Option(None, "--grace", help="Seconds the server stays up after the run finished or "
                                       "failed, unless a client calls stop() (0 to 86400; default 60)."),
) -> None:
    """Serve the line over OPC UA for a PLC (lockstep, or real time with --realtime); when it ends (its duration in
    real time, a client's stop(), Ctrl-C/SIGTERM) the run is written like any run."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    if lockstep and realtime is not None:
        raise InputError("--lockstep and --realtime exclude each other: give one")
    certificates = serving.certificates_of(certificate, private_key, trusted_clients, pki, user,
                                           users is not None or allow_anonymous_write)
    console = literal_console()

    def ready(line) -> None:  # noqa: ANN001
        mode = "lockstep (clients call step(n))" if line.realtime is None else f"real time x{line.realtime:g}"
        anonymous = {None: "refused", "viewer": "read only", "operator": "read, write and call"}[
            line.users.anonymous_role]
        console.print(f"serving {scenario} at {line.endpoint} (namespace urn:fishfmu, object fishfmu), {mode}; "
                      f"clients write: {', '.join(line.external) or 'nothing'}; anonymous clients: {anonymous}"
                      + (f"; live view at http://{line.live_at}/" if line.live_at else ""))

    done = commands.serve(scenario, out, parse_assignments(set_), endpoint=endpoint, realtime=realtime,
                          allow_remote=allow_remote, user=user, certificates=certificates, overwrite=overwrite,
                          report=report, on_ready=ready, wait_for_start=wait_for_start, grace_s=grace,
                          users_file=users, allow_anonymous_write=allow_anonymous_write, pki=pki, modbus=modbus, live=live)
    result = done.result
    pacing = (result.served or {}).get("pacing")
    if pacing:
        console.print(f"pacing x{pacing['factor']:g}: lateness p50 {1e3 * pacing['lateness_p50_s']:.2f} ms, p99 "
                      f"{1e3 * pacing['lateness_p99_s']:.2f} ms, max {1e3 * pacing['lateness_max_s']:.2f} ms; "
                      f"{pacing['overruns']} of {pacing['steps']} steps overran")
    _finish(result, done.out_dir, done.stop_exit_code, console)


app.command("hash-password")(serving.hash_password_cmd)
app.command("signal-list")(serving.signal_list_cmd)
app.command("export-fmu")(export.export_fmu_cmd)
app.command("export-ssp")(export.export_ssp_cmd)


@app.command("check")
def check_cmd(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML)."),
    set_: list[str] = typer.Option([], "--set", help="Override a scenario value: --set fish.count=30 (repeatable)."),
    as_json: bool = typer.Option(False, "--json", help="Print the outcome as JSON."),
) -> None:
    """Check a scenario without running it: exit 0 and the stepping order, delayed links, conversions,
    setpoints and recorded variables; exit 2 and what is wrong."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    doc = commands.check(scenario, parse_assignments(set_))
    if as_json:
        print(json.dumps(doc, indent=2))
        return
    console = literal_console()
    console.print(f"{scenario}: ok ({len(doc['fmus'])} FMUs, {doc['coupling']} coupling)")
    console.print("stepping order: " + " -> ".join(doc["stepping_order"]))
    for d in doc["delayed_links"]:
        console.print(f"one step late: {d['connection']} ({d['why']})")
    for c in doc["conversions"]:
        extra = ", ".join(f"{k} {c[k]:g}" for k in ("gain", "offset") if c[k] is not None) + (", rounded" if c["round"] else "")
        console.print(f"converted: {c['connection']}: {c['from']} -> {c['to']}" + (f" ({extra})" if extra else ""))
    for cid, key in doc["setpoints"].items():
        console.print(f"setpoint of {cid} in belts.csv: {key}")
    if doc["recorded"]:
        console.print("recorded besides the connections: " + ", ".join(doc["recorded"]))
    if doc["external_inputs"]:
        console.print("written by OPC UA clients (fishfmu serve): " + ", ".join(doc["external_inputs"]))
    for text in doc["ssp_not_imported"]:
        console.print(f"not imported from [system] ssp: {text} (a connector of the system itself; wire the plant's "
                      "links in [wiring])")


def _print_seeds(result, scenario: Path, out_dir: Path) -> None:  # noqa: ANN001
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from plant.contract.kpis import SHOWN_KPI_KEYS
    from fishfmu.batch.sweep_report import print_statistics
    console = literal_console()
    seeds = result.sweep.runs["seed"]
    print_statistics(result.statistics, SHOWN_KPI_KEYS, console,
                     f"KPIs: {scenario.stem}, seeds {seeds.min()}-{seeds.max()} "
                     f"({int(result.statistics['n_ok'])} ok, {result.n_failed} failed), {result.sweep.wall_s:.0f} s")
    if result.n_failed:
        console.print(labelled("failed runs:", result.statistics["errors"], "red"))
    for e in result.expect:
        console.print(outcome(e.ok, "mean " + e.message))
    if result.sweep.interrupted:
        console.print(labelled("stopped:", f"by {signal.Signals(result.sweep.stop_signal).name}; the "
                               "statistics cover the runs that finished (run_info.json: partial)", "yellow"))
    console.print(f"outputs: {out_dir}")


# ---------------------------------------------------------------- sweep

@app.command("sweep")
def sweep(
    scenario: Path = typer.Argument(..., help="Scenario file (TOML)."),
    param: list[str] = typer.Option([], "--param", help="Swept key and values: --param fish.length_mean_m=0.5,0.6 "
                                                         "or KEY=START:STOP:N (repeatable; every combination runs)."),
    seeds: int = typer.Option(5, "--seeds", min=1, help="Fish batches per point: run.seed and the N-1 after it."),
    out: Path = typer.Option(..., "--out", help="Sweep folder; the same command on the same folder resumes."),
    set_: list[str] = typer.Option([], "--set", help="Fixed override at every point: --set fish.count=30."),
    scale: list[str] = typer.Option([], "--scale", help="A named factor on several keys, swept with --param NAME=...: "
                                                         "--scale speed='fmu[0].parameters.speed_1,fmu[0].parameters.speed_2'"),
    scheduler: str | None = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler "
                                                                   "(default: a local cluster)."),
    workers: int | None = typer.Option(None, "--workers", help="Local worker processes (default: cores)."),
    threads_per_worker: int = typer.Option(1, "--threads-per-worker", min=1, help="Threads per local worker."),
    max_runs: int | None = typer.Option(None, "--max-runs", min=0, help="Stop after this many runs (resume later)."),
    retry_failed: bool = typer.Option(False, "--retry-failed", help="Re-run failed runs when resuming."),
) -> None:
    """Sweep parameters x seeds on Dask: runs/summary tables (parquet, CSV) and plots with 95 % CI bands."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.batch.sweep_spec import parse_param
    from fishfmu.batch.sweep_report import print_summary
    fixed = parse_assignments(set_)
    params = dict(parse_param(p) for p in param)
    if len(params) != len(param):
        raise InputError("a key is given twice with --param")
    scales = {}
    for item in scale:
        name, eq, keys = item.partition("=")
        if not eq or not name.strip() or not keys.strip():
            raise InputError(f"--scale '{item}': expected NAME=KEY1,KEY2,...")
        scales[name.strip()] = [k.strip() for k in keys.split(",") if k.strip()]
    spec, result = commands.sweep(scenario, params, seeds, out, fixed, scales=scales, scheduler=scheduler,
                                  workers=workers,
                                  threads_per_worker=threads_per_worker, progress=_show_progress(),
                                  max_runs=max_runs, retry_failed=retry_failed)
    console = literal_console()
    if len(result.summary):
        print_summary(result.summary, list(spec.parameters), console, title=scenario.stem)
    done = len(result.runs)
    console.print(f"{done} of {result.n_runs} runs done ({result.n_executed} now, {result.n_skipped} from before), "
                  f"{int((result.runs['status'] != 'ok').sum()) if done else 0} failed, {result.wall_s:.0f} s; "
                  f"tables and plots in {result.out}")
    if result.interrupted:
        console.print(labelled("stopped:", f"by {signal.Signals(result.stop_signal).name}; run the "
                               "same command again to resume", "yellow"))
        raise typer.Exit(for_signal(result.stop_signal))


# ---------------------------------------------------------------- replay

@app.command("replay")
def replay_cmd(
    run_dir: Path = typer.Argument(..., help="Output folder of a `fishfmu run --replay`."),
    out: Path | None = typer.Option(None, "--out", help="HTML file to write (default: RUN_DIR/replay.html)."),
) -> None:
    """Write a run as one HTML page that replays it in 3D in a browser (offline, from the file)."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    print(commands.replay(run_dir, out))


# ---------------------------------------------------------------- compare and diagnose

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
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    done = commands.compare(dataset, out, scenario, workers, overwrite)
    table = Table(title=f"{done.dataset_name}: simulated - measured, over {done.n_runs} runs")
    for col in ("measure", "mean", "sd", "min", "max"):
        table.add_column(col, justify="right" if col != "measure" else "left")
    for row in done.comparison.summary().itertuples():
        table.add_row(row.measure, *[f"{getattr(row, k):.4g}" for k in ("mean", "sd", "min", "max")])
    literal_console().print(table)
    for why in (done.comparison.not_replayed or {}).values():
        err_console.print(labelled("not replayed:", f"{why}; the KPIs they change, and arrivals and tracks from the "
                                   "first device on, are not compared (compare.json: not_replayed)", "bold yellow"))
    literal_console().print(f"report: {done.paths['report']}")
    if done.stopped_by is not None:
        err_console.print(labelled("stopped:", f"by {done.stopped_by}; runs not re-simulated are listed as "
                                   f"failed in {done.out_dir / 'compare.json'}", "bold yellow"))
        raise typer.Exit(done.stop_exit_code)
    if done.failure:
        raise SimulationError(f"{done.failure} (what the other runs gave is written to {done.out_dir})")


@app.command("diagnose")
def diagnose_cmd(
    dataset: Path = typer.Argument(..., help="Measured dataset folder (contracts/measured-data.md)."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    scenario: Path | None = typer.Option(None, "--scenario", help="Start from this scenario's plant parameters."),
    workers: int | None = typer.Option(None, "--workers", help="Parallel processes (default: all cores)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier result in --out."),
    calibrate: bool = typer.Option(True, "--calibrate/--no-calibrate", help="First fit the base model to the "
                                   "data (fishfmu calibrate); --no-calibrate: take it as given (--scenario)."),
    without: list[str] = typer.Option([], "--without", help="Leave this candidate cause out (repeatable)."),
) -> None:
    """Calibrate the base model, then name the causes of what it still gets wrong (or say that it fits, or where an
    unexplained discrepancy is), fit them, and measure the gain on held-out runs."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.analysis.calibrate_report import summary_lines
    from fishfmu.analysis.diagnose_report import candidate_lines, decision_text, extension_text
    done = commands.diagnose(dataset, out, scenario, workers, overwrite,
                             progress=lambda text: err_console.print(text), calibrate=calibrate,
                             without=tuple(without))
    d, paths = done.diagnosis, done.paths
    if d.calibration is not None:
        for line in summary_lines(d.calibration, d.calibration.base):
            literal_console().print("calibration: " + line)
    for line in candidate_lines(d):
        literal_console().print("candidate " + line)
    literal_console().print(labelled("answer:", d.answer, "bold"))
    literal_console().print(labelled("cause:", d.cause, "bold"))
    for f in d.unexplained:
        literal_console().print("unexplained: " + f.text)
    literal_console().print("extension: " + extension_text(d))
    literal_console().print(decision_text(d))
    literal_console().print(f"diagnosis: {paths['json']}\nfragment: {paths['fragment']}\nreport: {paths['report']}")


@app.command("calibrate")
def calibrate_cmd(
    dataset: Path = typer.Argument(..., help="Measured dataset folder (contracts/measured-data.md)."),
    out: Path = typer.Option(..., "--out", help="Output folder: calibrated.toml and calibration.json."),
    scenario: Path | None = typer.Option(None, "--scenario", help="Start from this scenario's plant parameters."),
    workers: int | None = typer.Option(None, "--workers", help="Parallel processes (default: all cores)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier result in --out."),
) -> None:
    """Fit the line's constants (one friction level, one joint stiffening, the drives' ramps) on the runs with most
    fish alone, checked on held-out runs; the result is a fragment for --scenario of compare and diagnose."""
    # slow: imported when the command runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.analysis.calibrate_report import summary_lines
    done = commands.calibrate(dataset, out, scenario, workers, overwrite, progress=lambda text: err_console.print(text))
    console = literal_console()
    for line in summary_lines(done.calibration, done.base):
        console.print(line)
    console.print(f"fragment: {done.paths['fragment']}\ncalibration: {done.paths['json']}")


def main() -> None:
    """Entry point: turn our own errors into one clear line and the matching exit code (:mod:`.exit_codes`)."""
    s = None
    try:
        with session() as s:  # SIGINT/SIGTERM: workers stopped, temporary folder removed, exit 130/143
            app(standalone_mode=True)
    except Interrupted as exc:  # the session has told the output folder (run_info.json: partial)
        where = f"; what finished is in {s.out_dir} (run_info.json: {_status(s.out_dir)})" \
            if s and s.out_dir is not None else ""
        if getattr(exc, "written", None) is not None:  # a benchmark's results so far
            where = f"; what it measured is in {exc.written} (status: partial)"
        err_console.print(labelled("stopped:", f"by {exc.signal_name}{where}", "bold yellow"))
        sys.exit(exc.exit_code)
    except Exception as exc:
        known = for_error(exc)
        if known is None:  # a bug: say so in one line, with where it happened (traceback on request)
            _internal_error(exc)
        label, message, code = known
        print_error(label, message)
        sys.exit(code)


def _status(out_dir: Path) -> str:
    """What ``run_info.json`` says now (a signal that came after the folder was finished leaves it as it was)."""
    try:
        return str(json.loads((out_dir / "run_info.json").read_text())["status"])
    except (OSError, ValueError, KeyError, TypeError):
        return "partial"


def _internal_error(exc: Exception) -> None:
    """A bug: one line saying where it happened (the traceback with FISHFMU_DEBUG=1); exit 4."""
    if os.environ.get("FISHFMU_DEBUG"):
        raise exc
    frame = traceback.extract_tb(exc.__traceback__)[-1]
    err_console.print(labelled("internal error", "(a bug in fishfmu; please report it, FISHFMU_DEBUG=1 shows "
                               f"the traceback): {type(exc).__name__}: {exc} "
                               f"[{Path(frame.filename).name}:{frame.lineno}]", "bold red"))
    sys.exit(EXIT_INTERNAL_ERROR)
