"""Parameter sweeps with Monte-Carlo seeds: every combination of values, each over N fish batches.

A sweep is a scenario file, fixed overrides, swept keys with their values and a list of seeds.
Every (point, seed) is one run with ``run.seed = seed``; the seeds are the scenario's own
``run.seed`` and the N - 1 after it (1..N for the shipped scenarios), the same at every point, so
that two points are compared on the same fish batches (common random numbers) and a run's result
depends only on its point and seed, never on the worker or the order.

Its folder (``out``) holds ``sweep.json`` (the definition), ``points/<run id>.json`` (one file per
finished run, written atomically: what a resumed sweep skips), ``runs.parquet/csv`` (one row per
run), ``summary.parquet/csv`` (one row per point: mean and confidence interval per KPI, see
:mod:`fishfmu.batch.stats`) and ``plots/``.  Re-running the same sweep into the same folder runs only
what is missing; a different definition is refused.  What a sweep runs, and each point checked before any run:
:mod:`fishfmu.batch.sweep_spec`.
"""

from __future__ import annotations

import itertools
import json
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from plant.errors import InputError
from plant.contract.kpis import KPI_KEYS

from fishfmu.batch.engine import FINAL_ERROR_KINDS, RunTask, Row, execute, failed_row, fmu_bundle, progress_bar
from fishfmu.batch.sweep_report import write_plots
from fishfmu.batch.sweep_spec import PointPreparer, SweepSpec, run_id
from fishfmu.output.atomic import json_safe, write_file_atomic, write_json_atomic, write_text_atomic
from fishfmu.output.manifest import note_dir
from fishfmu.output.manifest_state import is_internal
from fishfmu.output.ownership import open_resumable
from fishfmu.output.run_folder import RunFolder
from fishfmu.session import STOPS

DEFINITION = "sweep.json"
"""The sweep's definition in its folder (:meth:`fishfmu.batch.sweep_spec.SweepSpec.definition`)."""


# ---------------------------------------------------------------- the folder

def open_folder(out: Path, spec: SweepSpec) -> Path:
    """Create the sweep folder, or accept one holding this very sweep; refuse anything else."""
    definition = spec.definition()
    out = open_resumable(Path(out), [spec.scenario])  # refuses a folder holding anything fishfmu did not write
    if (out / DEFINITION).is_file():
        old = json.loads((out / DEFINITION).read_text())
        differ = [k for k in definition if old.get(k) != definition[k]]
        if differ:
            raise InputError(f"holds a different sweep ({', '.join(differ)} differ); use another --out to start a new "
                             "sweep, or the same command as before to resume this one", file=out)
    elif any(not is_internal(p.name) for p in out.iterdir()):
        raise InputError("folder is not empty and holds no sweep; choose another --out", file=out)
    else:
        write_json_atomic(out / DEFINITION, definition)
    (out / "points").mkdir(parents=True, exist_ok=True)
    note_dir(out / "points")
    return out


def finished_rows(out: Path) -> dict[str, Row]:
    rows = {}
    for p in sorted((out / "points").glob("*.json")):
        row = json.loads(p.read_text())
        rows[row["run_id"]] = row
    return rows


def store_row(out: Path, row: Row) -> None:
    write_json_atomic(out / "points" / f"{row['run_id']}.json", json_safe(row))


# ---------------------------------------------------------------- running

@dataclass
class SweepResult:
    out: Path
    runs: pd.DataFrame
    summary: pd.DataFrame
    n_runs: int
    """runs in the whole sweep (points x seeds)"""
    n_executed: int
    """runs executed by this call"""
    n_skipped: int
    """runs found finished in the folder"""
    interrupted: bool
    wall_s: float
    paths: dict[str, Path] = field(default_factory=dict)
    stop_signal: int | None = None
    """the signal that stopped it (SIGINT, SIGTERM) when ``interrupted``"""


def run_sweep(spec: SweepSpec, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              threads_per_worker: int = 1, progress: bool = False, max_runs: int | None = None,
              retry_failed: bool = False, plots: bool = True,
              cluster_kwargs: dict[str, Any] | None = None) -> SweepResult:
    """Run what is missing of the sweep in ``out`` on Dask, then write its tables and plots.

    ``max_runs``: run at most this many of the missing runs now (the rest on a later call).
    ``retry_failed``: also re-run failed runs (runs that crashed or raised are re-run anyway).
    Ctrl-C (or SIGINT/SIGTERM under the command, see :func:`fishfmu.session.session`) stops the
    runs: what finished is kept, the tables are written from it (no plots) and ``interrupted`` is set.
    """
    t0 = time.perf_counter()
    out = open_folder(Path(out), spec)
    folder = RunFolder.start(out, command="sweep")  # "partial" if stopped outside the runs, "running" if killed
    done = finished_rows(out)
    keep = {k: r for k, r in done.items() if r["status"] == "ok" or (r["error_kind"] in FINAL_ERROR_KINDS
                                                                     and not retry_failed)}
    points = spec.points()
    tasks: list[RunTask] = []
    meta: dict[str, dict[str, Any]] = {}
    todo: list[tuple[dict[str, Any], dict[int, str], list[int]]] = []
    """(point, run id by seed, the seeds still to run) of every point with a run to do"""
    for params in points:
        ids = {seed: run_id(params, seed) for seed in spec.seeds}
        point_id = run_id(params)
        for seed, rid in ids.items():
            meta[rid] = {"point_id": point_id, "params": params, "seed": seed}
        missing = [seed for seed, rid in ids.items() if rid not in keep]
        if missing:
            todo.append((params, ids, missing))
    executed, stop_signal = 0, None

    def on_row(row: Row) -> None:
        nonlocal executed
        store_row(out, {**row, **meta[row["run_id"]]})
        executed += 1

    try:  # a signal (Ctrl-C, or SIGTERM under the command) while checking or running: keep what finished
        preparer = PointPreparer(spec)
        with progress_bar(len(todo), progress and len(todo) > 1, "points checked") as advance:
            for params, ids, missing in todo:  # each point prepared once, its seeds sharing it
                try:
                    base = preparer.prepare(params)
                except InputError as exc:  # a bad value: recorded without sending anything to a worker
                    for seed in missing:
                        store_row(out, {**failed_row(ids[seed], "input", str(exc)), **meta[ids[seed]]})
                    advance({"status": "failed"})
                    continue
                for seed in missing:  # the runs of a point differ in the seed only: the rest is shared, not copied
                    sc = base.model_copy(update={"run": base.run.model_copy(update={"seed": seed})})
                    tasks.append(RunTask(ids[seed], sc, spec.scenario))
                advance({"status": "ok"})
        if max_runs is not None:
            tasks = tasks[:max_runs]
        if tasks:
            execute(tasks, fmu_bundle(t.scenario for t in tasks), on_row, scheduler=scheduler, workers=workers,
                    threads_per_worker=threads_per_worker, progress=progress, cluster_kwargs=cluster_kwargs)
    except STOPS as exc:
        stop_signal = getattr(exc, "signum", signal.SIGINT)
    interrupted = stop_signal is not None
    rows = [r for r in finished_rows(out).values() if r["run_id"] in meta]
    runs, summary = tables(spec, rows)
    paths = write_tables(out, runs, summary)
    if plots and not interrupted:
        paths["plots"] = write_plots(summary, list(spec.parameters), out / "plots")
    n_runs = len(points) * len(spec.seeds)
    folder.finish("partial" if interrupted or len(rows) < n_runs else "ok", n_runs=n_runs, n_done=len(rows),
                  stopped_by=signal.Signals(stop_signal).name if interrupted else None)
    return SweepResult(out, runs, summary, n_runs, executed, len(keep), interrupted, time.perf_counter() - t0, paths,
                       stop_signal)


# ---------------------------------------------------------------- tables

def tables(spec: SweepSpec, rows: list[Row]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(runs, summary): one row per run in sweep order, one row per point with KPI statistics."""
    from fishfmu.batch.stats import summarise  # slow: scipy (1 s), and fishfmu.commands imports this module
    order = {run_id(p, s): i for i, (p, s) in enumerate(itertools.product(spec.points(), spec.seeds))}
    rows = sorted(rows, key=lambda r: order.get(r["run_id"], len(order)))
    extra = sorted({k for r in rows for k in r.get("kpis", {}) if k not in KPI_KEYS})
    records = []
    for r in rows:
        rec = {"run_id": r["run_id"], "point_id": r["point_id"], **r["params"], "seed": r["seed"],
               "status": r["status"], "error_kind": r.get("error_kind"), "error": r.get("error")}
        rec.update({k: r.get("kpis", {}).get(k) for k in (*KPI_KEYS, *extra)})
        rec.update({k: r.get(k) for k in ("t_end_s", "wall_s", "task_s", "worker")})
        records.append(rec)
    columns = ["run_id", "point_id", *spec.parameters, "seed", "status", "error_kind", "error", *KPI_KEYS, *extra,
               "t_end_s", "wall_s", "task_s", "worker"]
    runs = pd.DataFrame.from_records(records, columns=columns)
    for k in KPI_KEYS:
        runs[k] = pd.to_numeric(runs[k], errors="coerce")
    summary = summarise(runs, ["point_id", *spec.parameters], KPI_KEYS) if len(runs) else pd.DataFrame()
    return _table_safe(runs), _table_safe(summary)


def _table_safe(df: pd.DataFrame) -> pd.DataFrame:
    """Parquet wants one type per column: a parameter column mixing numbers and text becomes text."""
    for c in df.columns:
        if df[c].dtype == object:
            kinds = {type(v) for v in df[c] if v is not None and v == v}
            if len(kinds) > 1 or kinds & {list, dict}:
                df[c] = [None if v is None else (json.dumps(v) if isinstance(v, (list, dict)) else str(v))
                         for v in df[c]]
    return df


def write_tables(out: Path, runs: pd.DataFrame, summary: pd.DataFrame) -> dict[str, Path]:
    """runs/summary as parquet and CSV, each written to a temporary name and renamed into place."""
    paths = {}
    for name, df in (("runs", runs), ("summary", summary)):
        paths[f"{name}_parquet"] = out / f"{name}.parquet"
        write_file_atomic(paths[f"{name}_parquet"], lambda fh, df=df: df.to_parquet(fh, index=False))
        paths[f"{name}_csv"] = out / f"{name}.csv"
        write_text_atomic(paths[f"{name}_csv"], df.to_csv(index=False, float_format="%.10g"))
    return paths
