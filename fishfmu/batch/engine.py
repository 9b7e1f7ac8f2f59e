"""Many runs in parallel on Dask: one task per scenario run, results as plain rows.

The client validates every scenario and builds the FMUs; a worker only runs.  A worker need not
have a compiler, the FMU cache or the user's files: the FMUs travel with the tasks as an
:class:`FmuBundle` (scattered once to every worker) and each worker puts them into its own cache
(built-in FMUs, under the client's source digest, where :func:`~fishfmu.fmu.build.builtin_fmu`
finds them) or a content-addressed folder (user FMUs).  Workers do need the same fishfmu version.

Nothing a run does stops the others: :func:`run_task` turns every exception into a failed row,
and a task whose worker died comes back as a failed row too (``error_kind = "crash"``).

>>> tasks = []                                                      # doctest: +SKIP
>>> execute(tasks, fmu_bundle([]), on_row=print, workers=2)         # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import signal
import socket
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from plant.errors import InputError, SimulationError

from fishfmu.fmu.build import builtin_fmu, cache_dir, install_cached_fmu, source_digest
from fishfmu.output.atomic import json_safe
from fishfmu.scenario.schema import Scenario
from fishfmu.session import deferred_signals
from fishfmu.terminal import console as literal_console

Row = dict[str, Any]
FINAL_ERROR_KINDS = ("input", "simulation")
"""Failures that a re-run would repeat (bad value, blow-up, FMU error); others are retried on resume."""


@dataclass(frozen=True)
class RunTask:
    """One scenario run: the validated scenario (its ``run.seed`` set) and an id for its row."""

    run_id: str
    scenario: Scenario
    scenario_file: str


@dataclass(frozen=True)
class FmuBundle:
    """The FMU files the runs need, as bytes: built-in ones by name, user ones by client path."""

    builtin: dict[str, tuple[str, bytes]] = field(default_factory=dict)
    """name -> (source digest, .fmu bytes)"""
    files: dict[str, tuple[str, bytes]] = field(default_factory=dict)
    """absolute path on the client -> (sha256, .fmu bytes)"""


def fmu_bundle(scenarios: Iterable[Scenario]) -> FmuBundle:
    """Build (or take from the cache) every built-in FMU the scenarios use and read their user FMUs."""
    builtin: dict[str, tuple[str, bytes]] = {}
    files: dict[str, tuple[str, bytes]] = {}
    for sc in scenarios:
        for f in sc.fmu:
            if f.builtin is not None and f.builtin not in builtin:
                builtin[f.builtin] = (source_digest(f.builtin), builtin_fmu(f.builtin).read_bytes())
            elif f.path is not None and f.path not in files:
                data = Path(f.path).read_bytes()
                files[f.path] = (hashlib.sha256(data).hexdigest(), data)
    return FmuBundle(builtin, files)


_installed: dict[tuple[str, str], str] = {}  # per worker process: (client path, sha) -> local path


def install_bundle(bundle: FmuBundle) -> dict[str, str]:
    """On a worker: make every FMU of the bundle available; returns client path -> local path."""
    for name, (digest, data) in bundle.builtin.items():
        install_cached_fmu(name, digest, data)
    local: dict[str, str] = {}
    for path, (sha, data) in bundle.files.items():
        if (path, sha) not in _installed:
            p = Path(path)
            if p.is_file() and hashlib.sha256(p.read_bytes()).hexdigest() == sha:
                _installed[(path, sha)] = path  # same machine or shared disk: use the file itself
            else:
                target = cache_dir() / "user" / sha[:20] / p.name
                if not target.is_file():
                    target.parent.mkdir(parents=True, exist_ok=True)
                    fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".part")
                    with os.fdopen(fd, "wb") as fh:
                        fh.write(data)
                    os.replace(tmp, target)
                _installed[(path, sha)] = str(target)
        local[path] = _installed[(path, sha)]
    return local


def scalar_kpis(kpis: dict[str, Any]) -> dict[str, Any]:
    """The KPIs that fit a table cell (numbers, text, flags), JSON-safe (:func:`fishfmu.output.run_folder.json_safe`:
    NaN/inf -> None, numpy -> Python)."""
    return {k: v for k, v in json_safe(kpis).items() if v is None or isinstance(v, (bool, int, float, str))}


def _worker_name() -> str:
    try:
        from distributed import get_worker  # slow and optional: Dask, only when this runs on a Dask worker
        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def failed_row(run_id: str, kind: str, error: str) -> Row:
    return {"run_id": run_id, "status": "failed", "error_kind": kind, "error": error, "kpis": {},
            "t_end_s": None, "wall_s": None, "task_s": None, "worker": None}


def run_task(task: RunTask, bundle: FmuBundle) -> Row:
    """Run one scenario (on a worker); never raises: a failure is a row with its error."""
    t0 = time.perf_counter()
    try:
        local = install_bundle(bundle)
        sc = task.scenario
        if any(f.path is not None and local.get(f.path, f.path) != f.path for f in sc.fmu):
            sc = sc.model_copy(deep=True)
            for f in sc.fmu:
                if f.path is not None:
                    f.path = local.get(f.path, f.path)
        # slow: Exudyn (the plant), which only a worker runs; the client that builds the tasks does not load it
        from fishfmu.cosim.runner import run_scenario
        result = run_scenario(sc, task.scenario_file)
        row: Row = {"run_id": task.run_id, "status": result.status,
                    "error_kind": None if result.status == "ok" else "simulation", "error": result.error,
                    "kpis": scalar_kpis(result.kpis) if result.status == "ok" else {},
                    "t_end_s": result.t_end_s, "wall_s": result.wall_s}
    except InputError as exc:
        row = failed_row(task.run_id, "input", str(exc))
    except SimulationError as exc:
        row = failed_row(task.run_id, "simulation", str(exc))
    except Exception as exc:  # a bug or the machine: recorded, and retried when the sweep is resumed
        row = failed_row(task.run_id, "error", f"{type(exc).__name__}: {exc}")
    row.update(task_s=time.perf_counter() - t0, worker=_worker_name())
    return row


@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int | None, threads_per_worker: int, n_tasks: int,
                cluster_kwargs: dict[str, Any] | None = None) -> Iterator[Any]:
    """A client of the cluster at ``scheduler``, or of a local cluster of worker processes started here."""
    from distributed import Client, LocalCluster  # slow and optional: Dask, only when runs are executed
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise InputError(f"cannot reach the Dask scheduler at '{scheduler}': {exc}") from None
        with client:
            yield client
        return
    n = max(1, min(workers or os.cpu_count() or 1, n_tasks))
    with contextlib.ExitStack() as stack:
        # Dask's scratch space (dask-scratch-space) in a folder of ours, removed when the cluster is down
        scratch = stack.enter_context(tempfile.TemporaryDirectory(prefix="fishfmu-dask-", ignore_cleanup_errors=True))
        kwargs = {"preload": ["fishfmu.batch.engine"], "local_directory": scratch, **(cluster_kwargs or {})}
        with deferred_signals():  # a signal while the cluster starts stops it once it is up (no half-started workers)
            # processes: each Exudyn run holds the GIL; one thread per worker: one run per core
            cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=threads_per_worker,
                                                       processes=True, dashboard_address=None,
                                                       silence_logs=logging.ERROR, **kwargs))
            client = stack.enter_context(Client(cluster))
            client.wait_for_workers(n, timeout=300)  # closing a worker that is still registering makes it print tracebacks
        yield client


def dask_setup(worker: Any) -> None:
    """Preload of the local workers: Ctrl-C reaches the whole process group, but it is for the client,
    which cancels the runs and shuts the workers down in order (no tracebacks from every worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def progress_bar(total: int, enabled: bool, description: str = "runs") -> Iterator[Callable[[Row], None]]:
    """A rich progress bar on stderr over runs; yields the function to call per finished row."""
    if not enabled:
        yield lambda row: None
        return
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(), TimeRemainingColumn(),
                  console=literal_console(stderr=True), transient=False) as bar:
        task = bar.add_task(description, total=total, failed=0)
        failed = 0

        def advance(row: Row) -> None:
            nonlocal failed
            failed += row["status"] != "ok"
            bar.update(task, advance=1, failed=failed)

        yield advance


def execute(tasks: list[RunTask], bundle: FmuBundle, on_row: Callable[[Row], None], *, scheduler: str | None = None,
            workers: int | None = None, threads_per_worker: int = 1, progress: bool = False,
            cluster_kwargs: dict[str, Any] | None = None) -> None:
    """Run every task on Dask and call ``on_row`` with each row as it finishes (in any order).

    A KeyboardInterrupt (or :class:`fishfmu.session.Interrupted`, a command's SIGINT/SIGTERM)
    cancels what has not finished and propagates (rows already handed to ``on_row`` stay); the
    local cluster (client, scheduler, nannies, workers) is shut down and its scratch folder removed
    in any case.
    """
    if not tasks:
        return
    from distributed import as_completed  # slow and optional: Dask, only when runs are executed
    with dask_client(scheduler, workers, threads_per_worker, len(tasks), cluster_kwargs) as client, \
            progress_bar(len(tasks), progress) as advance:
        shared = client.scatter(bundle, broadcast=True, hash=False)  # once per worker, not once per task
        futures = {client.submit(run_task, t, shared, key=f"fishfmu-run-{t.run_id}-{os.urandom(4).hex()}",
                                 pure=False): t for t in tasks}
        try:
            for fut in as_completed(list(futures)):
                task = futures.pop(fut)
                if fut.status == "cancelled":
                    continue
                if fut.status == "error":  # the worker died (segfault, memory) or the task could not travel
                    exc = fut.exception()
                    row = failed_row(task.run_id, "crash", f"{type(exc).__name__}: {exc}")
                else:
                    row = fut.result()
                fut.release()
                on_row(row)
                advance(row)
        except BaseException:
            client.cancel(list(futures))
            raise
