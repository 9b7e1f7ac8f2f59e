"""Sweep throughput: scenario runs per minute on a local Dask cluster of 1, 2, ... workers.

    fishfmu bench sweep --runs 8 --workers 1 --workers 2          # paper scenario, seeds 1-8

Each setting runs the same seeds into a fresh folder; the wall time counts everything a user waits
for (cluster start, FMU transfer, runs, tables), so it is ``runs / wall time``.  Results go to
``bench-results/sweep_bench.json``.
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fishfmu.batch.sweep import run_sweep
from fishfmu.batch.sweep_spec import make_spec


def bench(scenario: str | Path = "scenarios/paper_dump.toml", n_runs: int = 8, workers: tuple[int, ...] = (1, 2),
          fixed: dict[str, Any] | None = None, on_result: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """Runs per minute for each worker count (same scenario, same seeds); ``on_result(result)`` after each count
    (an interrupted benchmark keeps what it measured)."""
    spec = make_spec(scenario, {}, n_runs, fixed or {})
    results = []
    for w in workers:
        with tempfile.TemporaryDirectory(prefix="fishfmu-bench-") as tmp:
            load_before = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = run_sweep(spec, Path(tmp) / "sweep", workers=w, plots=False)
            wall_s = time.perf_counter() - t0
        runs = res.runs
        results.append({
            "workers": w, "runs": len(runs), "failed": int((runs["status"] != "ok").sum()),
            "wall_s": round(wall_s, 2), "runs_per_min": round(60.0 * len(runs) / wall_s, 2),
            "task_s_mean": round(float(runs["task_s"].mean()), 2),
            "sim_s_mean": round(float(runs["t_end_s"].mean()), 2),
            "load_average_before": round(load_before, 2), "load_average_after": round(os.getloadavg()[0], 2)})
        if on_result is not None:
            on_result(results[-1])
    return {"scenario": str(scenario), "fixed": fixed or {}, "seeds": spec.seeds, "cores": os.cpu_count(),
            "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
            "results": results}


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    return [f"{r['workers']} worker(s): {r['runs']} runs in {r['wall_s']:.1f} s = {r['runs_per_min']:.2f} runs/min "
            f"(mean {r['task_s_mean']:.1f} s per run, {r['failed']} failed)" for r in doc["results"]]
