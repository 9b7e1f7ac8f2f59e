"""``fishfmu bench ...``: every benchmark, its results written to a file (JSON), never asserted in tests.

Each benchmark imports what it measures inside its function, saying so: ``fishfmu bench --help`` answers without
numpy, pandas and Exudyn.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer
from rich.table import Table

from plant.errors import InputError

from fishfmu.scenario.keys import parse_assignments
from fishfmu.terminal import console as literal_console

bench_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                        help="Benchmarks: results written to a file (JSON), never asserted in tests.")
err_console = literal_console(stderr=True)


@bench_app.command("pile")
def bench_pile(
    fish: str = typer.Option("18,50,100,200", "--fish", help="Fish counts, comma separated."),
    duration: float = typer.Option(5.0, "--duration", help="Simulated seconds measured after the drop."),
    comm_step: float = typer.Option(0.01, "--comm-step", help="Communication step [s]."),
    threads: int = typer.Option(1, "--threads", help="Exudyn threads."),
    json_file: Path | None = typer.Option(None, "--json", help="Write the records as a JSON list here."),
    plot_file: Path | None = typer.Option(None, "--plot", help="Write a PNG of cost against fish count here."),
) -> None:
    """Fish dumped in a pile: real-time factor of plant and co-simulation per fish count, stages, peak memory."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench import options
    from fishfmu.bench.pile import per_fish_cost, plot, records_json, run_bench
    try:
        counts = [int(x) for x in fish.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--fish '{fish}': expected comma-separated integers") from None
    if not counts:
        raise InputError(f"--fish '{fish}': give one or more fish counts")
    options.pile(counts, duration, comm_step, threads)
    _check_results(json_file, plot_file)
    console = literal_console()
    table = Table(title=f"fishfmu bench pile: {duration:g} s simulated after the drop, step {comm_step:g} s, "
                        f"{threads} thread(s)")
    for col in ("fish", "RTF plant", "RTF co-sim", "Exudyn", "plant py", "FMUs", "master", "recording",
                "FMU+master+rec", "peak MB"):
        table.add_column(col, justify="right")

    def row(r) -> None:
        w = r.wall_cosim_s
        table.add_row(str(r.fish), f"{r.rtf_plant:.2f}", f"{r.rtf_cosim:.2f}", f"{100 * r.plant_exudyn_s / w:.0f} %",
                      f"{100 * r.plant_python_s / w:.0f} %", f"{100 * r.fmu_s / w:.1f} %", f"{100 * r.master_s / w:.1f} %",
                      f"{100 * r.recording_s / w:.1f} %", f"{100 * r.overhead_fraction:.1f} %", f"{r.peak_rss_mb:.0f}")
        err_console.print(f"measured {r.fish} fish: RTF plant {r.rtf_plant:.2f}, co-sim {r.rtf_cosim:.2f}")

    done: list = []
    with _partial_results(json_file, "pile", lambda: {"records": records_json(done)}):
        records = run_bench(counts, duration, comm_step, threads, on_record=lambda r: (done.append(r), row(r)))
    console.print(table)
    base, per = per_fish_cost(records)
    console.print(f"plant step cost: {base:.2f} ms with no fish + {per:.3f} ms per fish (straight line through the "
                  "measured counts)")
    if json_file is not None:
        commands.write_json(json_file, records_json(records))
    if plot_file is not None:
        plot(records, plot_file)


@bench_app.command("fmu-worker")
def bench_fmu_worker(
    scenario: Path = typer.Option(Path("scenarios/paper_dump.toml"), "--scenario", help="Scenario file (TOML)."),
    steps: int = typer.Option(2000, "--steps", min=1, help="Communication steps per run (no fish)."),
    repeats: int = typer.Option(3, "--repeats", min=1),
    with_fish: bool = typer.Option(False, "--with-fish", help="Also the scenario as shipped, in both modes."),
    json_file: Path = typer.Option(Path("bench-results/fmu_worker_bench.json"), "--json", help="Results (JSON)."),
) -> None:
    """What running each FMU in a worker process costs per communication step."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench.fmu_worker import bench, summary
    _check_results(json_file, inputs=[scenario])
    doc = bench(scenario, steps, repeats, with_fish)
    _bench_done(summary(doc), commands.write_json(json_file, doc))


@bench_app.command("serve")
def bench_serve(
    factor: float = typer.Option(1.0, "--factor", help="Real-time factor to serve at."),
    continuous_s: float | None = typer.Option(None, "--continuous-s", help="Also this many seconds of the "
                                              "continuous line, controller inside and a PLC over OPC UA."),
    set_: list[str] = typer.Option([], "--set", help="Override in every served case: --set "
                                   "plant.numerics.threads=2 (repeatable)."),
    json_file: Path = typer.Option(Path("bench-results/serve_bench.json"), "--json", help="Results (JSON)."),
) -> None:
    """Real-time serving: each step's lateness against the wall clock, paper test and (optionally) continuous line."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench.serve import SCENARIOS, bench, summary
    from fishfmu.scenario.schema import load_scenario
    from fishfmu.bench import options
    options.serve(factor, continuous_s)
    overrides = parse_assignments(set_)
    for s in SCENARIOS:  # bad input before measuring
        load_scenario(s, overrides)
    _check_results(json_file, inputs=SCENARIOS)
    done: list = []
    with _partial_results(json_file, "serve", lambda: {"cases": done}):
        doc = bench(factor, continuous_s, set_, on_case=done.append)
    _bench_done(summary(doc), commands.write_json(json_file, doc))


@bench_app.command("sweep")
def bench_sweep(
    scenario: Path = typer.Option(Path("scenarios/paper_dump.toml"), "--scenario", help="Scenario file (TOML)."),
    runs: int = typer.Option(8, "--runs", min=1, help="Seeds per setting."),
    workers: list[int] = typer.Option([1, 2], "--workers", help="Worker counts to measure (repeatable)."),
    set_: list[str] = typer.Option([], "--set", help="Fixed override: --set fish.count=30 (repeatable)."),
    json_file: Path = typer.Option(Path("bench-results/sweep_bench.json"), "--json", help="Results (JSON)."),
) -> None:
    """Sweep throughput: scenario runs per minute on a local Dask cluster of 1, 2, ... workers."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench import options
    from fishfmu.bench.sweep import bench, summary
    from fishfmu.scenario.schema import load_scenario
    options.sweep(workers)
    overrides = parse_assignments(set_)
    commands.refuse_served(load_scenario(scenario, overrides), scenario)  # its inputs come from a PLC: not swept
    _check_results(json_file, inputs=[scenario])
    done: list = []
    with _partial_results(json_file, "sweep", lambda: {"scenario": str(scenario), "results": done}):
        doc = bench(scenario, runs, tuple(workers), overrides, on_result=done.append)
    _bench_done(summary(doc), commands.write_json(json_file, doc))


@bench_app.command("diagnose")
def bench_diagnose(
    seeds: int = typer.Option(5, "--seeds", min=1, help="Repetitions per hidden effect."),
    first_seed: int = typer.Option(100, "--first-seed"),
    strength: float = typer.Option(1.0, "--strength", help="Size of each hidden effect (1: as in the tests)."),
    workers: int = typer.Option(2, "--workers", min=1),
    json_file: Path = typer.Option(Path("bench-results/diagnose_bench.json"), "--json", help="Results (JSON)."),
    labelled: Path | None = typer.Option(None, "--labelled", help="Instead: diagnose every dataset in this folder "
                                         "that has a NAME.truth.json label beside it (calibrating first)."),
    recipe: Path | None = typer.Option(None, "--recipe", help="With --labelled: the benchmark's recipe (TOML, "
                                       "docs/diagnose-bench/recipe.toml): tables per split (dev, heldout)."),
    split: str | None = typer.Option(None, "--split", help="With --recipe: diagnose only this split's datasets."),
    open_set: bool = typer.Option(False, "--open-set", help="With --labelled: diagnose each single-effect dataset "
                                  "again with its family's candidate switched off (--without): leave-one-family-out."),
    rescore: list[Path] = typer.Option([], "--rescore", help="Instead: score again the diagnoses kept in the "
                                       "results (JSON) of an earlier --labelled run; nothing is diagnosed. Repeatable: "
                                       "the files merged in order, a later row replacing an earlier one of its "
                                       "dataset (its open-set run only where it has one)."),
) -> None:
    """How often diagnose names the hidden effect of a synthetic dataset, over many seeds (or of labelled data)."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench import options
    from fishfmu.bench.diagnose import (bench, bench_labelled, labelled_document, open_set_supported, read_splits,
                                        rescore as rescored, summary)
    options.diagnose(seeds, first_seed, strength)
    if rescore:
        if labelled is not None or open_set:
            raise InputError("--rescore: scores earlier results; not with --labelled or --open-set")
        _check_results(json_file, inputs=list(rescore))
        doc = rescored(rescore)
        _bench_done(summary(doc), commands.write_json(json_file, doc))
        return
    if open_set and labelled is None:
        raise InputError("--open-set: only with --labelled DIR (the open set is measured on labelled datasets)")
    if open_set and not open_set_supported():
        raise InputError("--open-set: this fishfmu's diagnose cannot switch a candidate off (no --without; issue 41)")
    _check_results(json_file, inputs=[labelled, recipe])
    rows: list = []
    if labelled is not None:
        if not labelled.is_dir():
            raise InputError(f"{labelled}: not a folder of labelled datasets")
        splits = read_splits(recipe)
        if split is not None and split not in set(splits.values()):
            raise InputError(f"--split {split}: no dataset of the recipe has that split "
                             f"(it has: {', '.join(sorted(set(splits.values()))) or 'none'})")
        with _partial_results(json_file, "diagnose", lambda: labelled_document(rows, labelled) if rows else {}):
            doc = bench_labelled(labelled, workers, on_row=lambda r: err_console.print(str(r)), splits=splits,
                                 only=split, open_set=open_set,
                                 on_done=lambda partial: (rows.__setitem__(slice(None), partial["runs"]),
                                                          commands.write_json(json_file, partial)))
    else:
        with _partial_results(json_file, "diagnose", lambda: {"runs": rows}):
            doc = bench(seeds, first_seed, strength, workers,
                        on_row=lambda r: (rows.append(r), err_console.print(str(r))))
    _bench_done(summary(doc), commands.write_json(json_file, doc))


def _check_results(*files: Path | None, inputs=()) -> None:  # noqa: ANN001
    """Before measuring: where the results go (:func:`fishfmu.bench.options.check_result_file`)."""
    from fishfmu.bench.options import check_result_file  # slow (the scenario schema): only when a benchmark runs
    for f in files:
        check_result_file(f, [Path(i) for i in inputs if i is not None])


@contextmanager
def _partial_results(json_file: Path | None, name: str, so_far: Any) -> Iterator[None]:
    """A benchmark stopped by a signal writes what it measured to ``json_file``, marked ``partial`` (``so_far()``:
    the results so far), then ends by the signal (exit 130/143, one line saying where they are)."""
    # only when a benchmark runs (commands imports numpy and pandas; --help answers without them)
    from fishfmu import commands
    from fishfmu.session import STOPS
    try:
        yield
    except STOPS as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        if json_file is not None:
            with contextlib.suppress(Exception):  # the signal is what is reported: a failed write only loses these
                commands.write_json(json_file, {"benchmark": name, "status": "partial",
                                                "stopped_by": signal.Signals(signum).name, **so_far()})
                exc.written = json_file  # type: ignore[union-attr]
        raise


def _bench_done(lines: list[str], written: Path) -> None:
    console = literal_console()
    for line in lines:
        console.print(line)
    console.print(f"written: {written}")


@bench_app.command("scenario")
def bench_scenario(
    scenarios: list[Path] = typer.Argument(..., help="Scenario files (TOML), each run as shipped."),
    repeats: int = typer.Option(1, "--repeats", min=1, help="Runs per scenario (the median is reported)."),
    set_: list[str] = typer.Option([], "--set", help="Override in every run: --set run.duration_s=60 (repeatable)."),
    json_file: Path = typer.Option(Path("bench-results/scenario_bench.json"), "--json", help="Results (JSON)."),
) -> None:
    """Whole scenarios: simulated s per CPU s of the whole process, stages, fish in play, peak memory."""
    # slow: imported when the benchmark runs (numpy, pandas, Exudyn; --help answers without them)
    from fishfmu import commands
    from fishfmu.bench.scenario import bench, summary
    from fishfmu.scenario.schema import load_scenario
    overrides = parse_assignments(set_)
    for s in scenarios:  # bad input before measuring
        load_scenario(s, overrides)
    _check_results(json_file, inputs=scenarios)
    done: list = []

    def record(r: dict) -> None:
        done.append(r)
        err_console.print(f"{Path(r['scenario']).stem}: {r['rtf_cpu']:.2f}x per CPU s")

    with _partial_results(json_file, "scenario", lambda: {"records": done}):
        doc = bench([str(s) for s in scenarios], repeats, overrides, on_record=record)
    _bench_done(summary(doc), commands.write_json(json_file, doc))

