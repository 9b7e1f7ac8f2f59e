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
what is missing; a different definition is refused.

>>> parse_param("fmu[0].parameters.speed_2=0.4,0.5")
('fmu[0].parameters.speed_2', [0.4, 0.5])
>>> parse_param("fish.length_mean_m=0.5:0.7:3")
('fish.length_mean_m', [0.5, 0.6, 0.7])
>>> parse_param("fish.count=10:30:3")
('fish.count', [10, 20, 30])
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from plant.errors import InputError
from plant.contract.kpis import KPI_KEYS

from fishfmu.batch.engine import FINAL_ERROR_KINDS, RunTask, Row, execute, failed_row, fmu_bundle, progress_bar
from fishfmu.batch.sweep_report import write_plots
from fishfmu.output.atomic import json_safe, write_file_atomic, write_json_atomic, write_text_atomic
from fishfmu.output.manifest import is_internal, note_dir
from fishfmu.output.ownership import open_resumable
from fishfmu.output.run_folder import RunFolder
from fishfmu.session import STOPS
from fishfmu.cosim.preflight import FmuDescription, check_start_values, describe_file, preflight, preflight_changes
from fishfmu.scenario.schema import (RunSettings, Scenario, ScenarioLoader, dotted_parts, get_dotted, load_scenario,
                                     parse_value)
from plant.validation import read_toml

DEFINITION = "sweep.json"
MAX_RUNS = 100_000
"""Runs in one sweep (points x seeds), and so values of one range: a run takes seconds to minutes of a
core (the paper test: about 10 s), so 100 000 runs are days of a 64-core cluster, and the sweep's
folder holds a file per run.  Larger sweeps are refused before anything is allocated."""
FORMAT = 1
MAX_SEED: int = next(m.le for m in RunSettings.model_fields["seed"].metadata if hasattr(m, "le"))
"""The largest ``run.seed`` (the schema's bound): a sweep's last seed must not pass it."""
_RANGE = re.compile(r"^\s*([-+]?[\d.eE+-]+)\s*:\s*([-+]?[\d.eE+-]+)\s*:\s*(\d+)\s*$")


# ---------------------------------------------------------------- the definition

@dataclass(frozen=True)
class SweepSpec:
    """What a sweep runs; ``parameters`` keeps the order given (the first varies slowest)."""

    scenario: str
    """absolute path of the scenario file"""
    parameters: dict[str, list[Any]]
    seeds: list[int]
    fixed: dict[str, Any] = field(default_factory=dict)
    """overrides applied at every point (``--set``)"""
    scales: dict[str, list[str]] = field(default_factory=dict)
    """named factors (``--scale NAME=KEY1,KEY2``): a swept NAME multiplies the scenario's value of each KEY
    (the belt speeds of a profile, scaled together)"""

    def definition(self) -> dict[str, Any]:
        """sweep.json: everything that decides the runs' results (the scenario file by its content too)."""
        return {"format": FORMAT, "scenario": self.scenario,
                "scenario_sha256": hashlib.sha256(Path(self.scenario).read_bytes()).hexdigest(),
                "fixed": self.fixed, "parameters": [[k, v] for k, v in self.parameters.items()], "seeds": self.seeds,
                **({"scales": self.scales} if self.scales else {})}

    def points(self) -> list[dict[str, Any]]:
        keys = list(self.parameters)
        return [dict(zip(keys, combo)) for combo in itertools.product(*self.parameters.values())]


def make_spec(scenario: str | Path, parameters: dict[str, list[Any]], n_seeds: int,
              fixed: dict[str, Any] | None = None, scales: dict[str, list[str]] | None = None) -> SweepSpec:
    """Check the sweep as a whole (the scenario with ``fixed`` must load) and choose the seeds."""
    fixed = dict(fixed or {})
    scales = {k: list(v) for k, v in (scales or {}).items()}
    for name, keys in scales.items():
        if name not in parameters:
            raise InputError(f"--scale {name}: not swept (give its factors with --param {name}=...)")
        if not keys:
            raise InputError(f"--scale {name}: no keys to scale")
        for key in keys:
            if key in parameters or key in fixed:
                raise InputError(f"--scale {name}: '{key}' is also swept or fixed (--param/--set)")
            value = get_dotted(read_toml(Path(scenario)), key, fixed)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"--scale {name}: '{key}' is {value!r} in the scenario, not a number to scale")
    if n_seeds < 1:
        raise InputError(f"--seeds must be at least 1 (got {n_seeds})")
    check_size(math.prod(len(v) for v in parameters.values()), n_seeds)
    for key, values in parameters.items():
        if key == "run.seed":
            raise InputError("sweep the seed with --seeds N, not as a parameter")
        if not values:
            raise InputError(f"parameter '{key}' has no values")
        if key in fixed:
            raise InputError(f"'{key}' is both swept and fixed (--set)")
    base = load_scenario(scenario, fixed)
    first = base.run.seed
    if first + n_seeds - 1 > MAX_SEED:
        raise InputError(f"--seeds {n_seeds}: the seeds run from run.seed = {first} to {first + n_seeds - 1}, past "
                         f"the largest seed ({MAX_SEED})")
    spec = SweepSpec(str(Path(scenario).resolve()), {k: list(v) for k, v in parameters.items()},
                     list(range(first, first + n_seeds)), fixed, scales)
    preparer = PointPreparer(spec)
    for key, values in spec.parameters.items():  # a key no value works for is a typo, not a failed point
        first_error = None
        for v in values:  # until one works: the points themselves are prepared once, when the sweep runs
            try:
                preparer.prepare({key: v})
                break
            except InputError as exc:
                first_error = first_error or exc
        else:
            raise InputError(f"--param {key}: no value works: {first_error}")
    return spec


def _split_top_level(text: str) -> list[str]:
    """Split at commas outside brackets and quotes (values may be TOML arrays or strings)."""
    parts, depth, quote, current = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(current)
            current = ""
            continue
        current += ch
    return [p.strip() for p in parts + [current]]


def parse_param(text: str) -> tuple[str, list[Any]]:
    """``KEY=V1,V2,...`` or ``KEY=START:STOP:N`` (N evenly spaced values, ends included)."""
    key, eq, values = text.partition("=")
    key = key.strip()
    if not eq or not key or not values.strip():
        raise InputError(f"--param '{text}': expected KEY=V1,V2,... or KEY=START:STOP:N")
    m = _RANGE.match(values)
    if m:
        if len(m.group(3).lstrip("0")) > len(str(MAX_RUNS)) or int(m.group(3)) > MAX_RUNS:
            raise InputError(f"--param '{text}': a range may have at most {MAX_RUNS} values (runs in a sweep: "
                             f"at most {MAX_RUNS}, points x seeds)")
        try:
            start, stop, n = float(m.group(1)), float(m.group(2)), int(m.group(3))
        except ValueError:
            raise InputError(f"--param '{text}': START and STOP of a range must be numbers") from None
        if n < 1:
            raise InputError(f"--param '{text}': a range needs at least one value")
        if not (math.isfinite(start) and math.isfinite(stop)):
            raise InputError(f"--param '{text}': START and STOP must be finite numbers (not NaN or inf)")
        ints = m.group(1).lstrip("+-").isdigit() and m.group(2).lstrip("+-").isdigit()
        grid = np.linspace(start, stop, n)
        if ints and np.allclose(grid, np.round(grid)):
            return key, [int(round(v)) for v in grid]
        return key, [float(f"{v:.12g}") for v in grid]  # 0.3, not 0.30000000000000004
    parsed = [parse_value(v) for v in _split_top_level(values)]
    if any(v == "" for v in parsed):
        raise InputError(f"--param '{text}': empty value")
    if len(parsed) > MAX_RUNS:
        raise InputError(f"--param '{text}': at most {MAX_RUNS} values (runs in a sweep: at most {MAX_RUNS})")
    if any(not _finite(v) for v in parsed):
        raise InputError(f"--param '{text}': NaN and inf are not values a scenario can take")
    return key, parsed


def _finite(value: Any) -> bool:
    """False for NaN or inf anywhere in a value (numbers, arrays, tables)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return False
        if isinstance(v, (list, tuple)):
            stack.extend(v)
        elif isinstance(v, dict):
            stack.extend(v.values())
    return True


def check_size(n_points: int, n_seeds: int) -> None:
    """Refuse a sweep of more than :data:`MAX_RUNS` runs (before anything is allocated for it)."""
    if n_seeds > MAX_RUNS or n_points * n_seeds > MAX_RUNS:
        raise InputError(f"{n_points} point(s) x {n_seeds} seed(s) = {n_points * n_seeds} runs; a sweep may have at "
                         f"most {MAX_RUNS} runs (split it, or sweep fewer values)")


def run_id(params: dict[str, Any], seed: int | None = None) -> str:
    """A stable id of a point (and seed): the same values give the same id in any process."""
    text = json.dumps({"params": params, "seed": seed}, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ---------------------------------------------------------------- checking points up front

class PointPreparer:
    """Validates the points of one sweep before any run, paying per point only for what differs between points.

    Once per sweep: the scenario file, its parameter files and SSP are read (:class:`ScenarioLoader`), each FMU's
    modelDescription is read, and the base scenario (with ``--set``) has its FMU start values and wiring checked
    (:func:`fishfmu.cosim.preflight.preflight`).  Per point: the scenario with the point's overrides is validated
    whole (pydantic: the cross-field checks too, a fraction of a millisecond), then preflight checks only what
    the overrides can change (:func:`fishfmu.cosim.preflight.preflight_changes`): nothing for ``[fish]``,
    ``[plant]`` or ``run.duration_s``, one FMU's start values for ``fmu[i].parameters.*``, everything for a key
    of the wiring.  Where the base itself fails preflight, every point is checked in full."""

    def __init__(self, spec: SweepSpec) -> None:
        self.spec = spec
        self.loader = ScenarioLoader(spec.scenario)
        self._described: dict[str, FmuDescription] = {}
        self._builtin: dict[str, str] = {}
        self._base_passed: bool | None = None
        self._base: Scenario | None = None

    def _descriptions(self, scenario: Scenario) -> dict[str, FmuDescription]:
        """Each FMU's description, read once per file (a built-in FMU's file found once per name)."""
        # slow: fishfmu.cosim.build loads Exudyn (the plant), which a sweep's client does not run
        from fishfmu.cosim.build import as_the_user_names_it, fmu_path
        fmus = {}
        for f in scenario.fmu:
            if f.builtin is not None:
                if f.builtin not in self._builtin:
                    self._builtin[f.builtin] = str(fmu_path(f))
                path = self._builtin[f.builtin]
            else:
                path = str(fmu_path(f))
            if path not in self._described:
                try:
                    self._described[path] = describe_file(path)
                except InputError as exc:
                    raise as_the_user_names_it(f, exc) from None
            fmus[f.name] = self._described[path]
        return fmus

    def _base_passes(self) -> bool:
        if self._base_passed is None:
            try:
                self._base = self.loader.load(self.spec.fixed)
                preflight(self._base, self.spec.scenario, self._descriptions(self._base))
                self._base_passed = True
            except InputError:
                self._base_passed = False
        return self._base_passed

    def prepare(self, params: dict[str, Any]) -> Scenario:
        """The point's scenario, validated as far as possible without running (raises InputError).

        It shares with the base scenario every top-level table the point's overrides leave alone (a sweep holds
        a scenario per point until its runs are sent: a few kB each rather than tens)."""
        overrides = point_overrides(self.spec, params, self.loader.data)
        sc = self.loader.load(overrides)
        fmus = self._descriptions(sc)
        keys = [k for k in overrides if k not in self.spec.fixed]
        changed = preflight_changes(keys)
        if changed is None or not self._base_passes():
            preflight(sc, self.spec.scenario, fmus)
        else:
            check_start_values(sc, self.spec.scenario, fmus, changed)
        tables = {dotted_parts(k)[0] for k in keys}
        self._base_passes()  # loads the base
        if self._base is None or "system" in tables:  # [system] ssp adds to [[fmu]] and [wiring]
            return sc
        return self._base.model_copy(update={t: getattr(sc, t) for t in tables})


def point_overrides(spec: SweepSpec, params: dict[str, Any], data: dict[str, Any] | None = None) -> dict[str, Any]:
    """The scenario overrides of a point: ``--set`` values, swept keys, and each swept scale factor times the
    scenario's value of the keys it scales (``data``: the scenario's TOML, when already read)."""
    out = dict(spec.fixed)
    if spec.scales and data is None:
        data = read_toml(Path(spec.scenario))
    for key, value in params.items():
        if key in spec.scales:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"--param {key}: a scale factor must be a number (got {value!r})")
            for scaled in spec.scales[key]:
                out[scaled] = float(get_dotted(data, scaled, spec.fixed)) * float(value)
        else:
            out[key] = value
    return out


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
