"""``fishfmu run SCENARIO --seeds N``: one scenario over N fish batches, KPIs as mean and CI.

The N runs are a sweep without parameters (same engine, same seeds rule: ``run.seed`` .. +N-1).
The output folder holds ``kpis.json`` (each KPI's mean as a plain number, as for a single run,
plus ``statistics`` per KPI and ``expect``), ``run_info.json``, and the sweep itself in
``seeds/`` (``runs.csv``, ``summary.csv``, ...).

Its exit code (:func:`fishfmu.cli.exit_codes.for_seeds`), as ``fishfmu run``'s: 3 when any seed's run failed,
else 1 when an ``[expect]`` bound fails **on the mean over seeds** (not on single runs, nor on the interval),
else 0.
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from plant.errors import InputError
from plant.contract.kpis import KPI_KEYS

from fishfmu.batch.sweep import SweepResult, run_sweep
from fishfmu.batch.sweep_spec import SweepSpec
from fishfmu.cosim.results import ExpectResult
from fishfmu.output.junit import write_junit
from fishfmu.output.run_folder import RunFolder
from fishfmu.scenario.schema import Scenario
from fishfmu.session import Interrupted


@dataclass
class SeedsResult:
    """The statistics of one scenario over seeds, and its [expect] bounds checked on the means."""

    sweep: SweepResult
    statistics: pd.Series
    """the sweep's single summary row (see :func:`fishfmu.batch.stats.summarise`)"""
    expect: list[ExpectResult]

    @property
    def n_failed(self) -> int:
        return int(self.statistics["n_failed"])


def run_over_seeds(scenario_file: Path, sc: Scenario, spec: SweepSpec, folder: RunFolder, *,
                   scheduler: str | None = None, workers: int | None = None, progress: bool = False) -> SeedsResult:
    """Run the scenario ``sc`` of ``scenario_file`` (loaded and checked) for the seeds of ``spec`` into ``folder``
    (open, ``running``): the sweep in ``seeds/``, then ``kpis.json`` and the finish of ``run_info.json``."""
    t0 = time.perf_counter()
    sweep = run_sweep(spec, folder.path / "seeds", scheduler=scheduler, workers=workers, progress=progress,
                      plots=False)
    stopped_by = signal.Signals(sweep.stop_signal).name if sweep.interrupted else None
    if sweep.summary.empty:
        if sweep.interrupted:  # stopped before any run finished: nothing to average, the folder says so
            folder.finish("partial", n_ok=0, n_failed=0, stopped_by=stopped_by,
                          wall_s=round(time.perf_counter() - t0, 3), workers=workers, scheduler=scheduler)
            raise Interrupted(sweep.stop_signal)
        raise InputError("no run finished", file=scenario_file)
    stats = sweep.summary.iloc[0]
    # bounds on recorded signals are checked by single runs (a signal has no mean over seeds)
    expect = [ExpectResult(k, _mean(stats, k), b.min, b.max) for k, b in sc.expect.items() if "." not in k]
    result = SeedsResult(sweep, stats, expect)
    status = "partial" if sweep.interrupted else ("failed" if result.n_failed else "ok")
    doc: dict[str, Any] = {k: _mean(stats, k) for k in KPI_KEYS}
    doc.update(status=status, seeds=spec.seeds, n_ok=int(stats["n_ok"]), n_failed=result.n_failed, errors=stats["errors"],
               statistics={k: {f: stats[f"{k}_{f}"] for f in ("n", "n_undefined", "mean", "sd", "ci_low", "ci_high")}
                           for k in KPI_KEYS},
               singulation_rate_pooled={f: stats.get(f"singulation_rate_{f}") for f in ("pooled", "wilson_low",
                                                                                        "wilson_high")},
               expect={e.kpi: {"value": e.value, "min": e.min, "max": e.max, "ok": e.ok, "on": "mean over seeds"}
                       for e in expect},
               expect_not_checked={k: "a bound on a signal is checked by a single run (fishfmu run), not on means"
                                   for k in sc.expect if "." in k})
    folder.write_kpis(doc)
    folder.finish(status, n_ok=int(stats["n_ok"]), n_failed=result.n_failed, stopped_by=stopped_by,
                  wall_s=round(time.perf_counter() - t0, 3), workers=workers, scheduler=scheduler)
    return result


def _mean(stats: pd.Series, kpi: str) -> float | None:
    v = stats.get(f"{kpi}_mean")
    return None if v is None or v != v else float(v)


def write_junit_means(result: SeedsResult, path: Path, scenario_file: str) -> None:
    """Each [expect] bound, checked on the mean over seeds, as a JUnit test case."""
    write_junit(path, f"fishfmu:{Path(scenario_file).stem}:seeds", "fishfmu.seeds", result.expect, on="mean",
                error=(f"{result.n_failed} runs failed", str(result.statistics["errors"])) if result.n_failed else None)
