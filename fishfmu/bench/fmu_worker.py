"""What running FMUs in worker processes costs per communication step.

    fishfmu bench fmu-worker                  # paper scenario's 5 FMUs, no fish, 2000 steps x 3
    fishfmu bench fmu-worker --with-fish      # also the whole paper test, in-process vs worker

The same scenario runs with ``run.fmu_process = "in-process"`` and ``"worker"``.  The master's FMU
stage (inputs set, ``do_step``, outputs read; :class:`fishfmu.cosim.master.StageClock`) is timed, so
the cost of isolation is measured directly: the time the master spends stepping FMUs per step,
worker minus in-process, for all FMUs and per FMU, plus the
start-up (one interpreter per FMU).  Without fish the plant costs little, so the wall time per step
shows the same difference.  ``--with-fish`` runs the paper test as shipped (18 fish) in both modes
to put the cost next to a real plant step.  Results go to ``bench-results/fmu_worker_bench.json``.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

from fishfmu.cosim.master import StageClock
from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.schema import load_scenario

NO_FISH = {"fish.count": 1, "fish.first_drop_s": 3600.0, "run.stop_when_clear": False, "expect": {}}


def measure(scenario: str | Path, process: str, overrides: dict[str, Any]) -> dict[str, float]:
    """One run: wall time per step, time in the master's FMU stage per step, set-up time."""
    sc = load_scenario(scenario, {**overrides, "run.fmu_process": process})
    clock = StageClock()
    t0 = time.perf_counter()
    result = run_scenario(sc, clock=clock)
    total = time.perf_counter() - t0
    if result.status != "ok":
        raise RuntimeError(f"benchmark run failed: {result.error}")
    steps = round(result.t_end_s / sc.run.comm_step_s)
    return {"steps": steps, "fmus": len(sc.fmu), "wall_ms_per_step": 1e3 * result.wall_s / steps,
            "fmu_ms_per_step": 1e3 * clock.totals_s["fmus"] / steps, "setup_s": result.timings_s["setup"],
            "total_s": total}


def bench(scenario: str | Path = "scenarios/paper_dump.toml", steps: int = 2000, repeats: int = 3,
          with_fish: bool = False) -> dict[str, Any]:
    overrides = {**NO_FISH, "run.duration_s": steps * 0.01, "run.comm_step_s": 0.01}
    runs: dict[str, list[dict[str, float]]] = {"in-process": [], "worker": []}
    load_before = os.getloadavg()[0]
    for _ in range(repeats):
        for process in runs:  # interleaved, so that a change of machine load hits both alike
            runs[process].append(measure(scenario, process, overrides))
    med = {p: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for p, rs in runs.items()}
    n_fmus = med["worker"]["fmus"]
    cost = med["worker"]["fmu_ms_per_step"] - med["in-process"]["fmu_ms_per_step"]
    doc: dict[str, Any] = {
        "scenario": str(scenario), "steps": steps, "repeats": repeats, "fmus": n_fmus,
        "in_process": med["in-process"], "worker": med["worker"], "runs": runs,
        "isolation_ms_per_step": round(cost, 4), "isolation_ms_per_fmu_step": round(cost / n_fmus, 4),
        "wall_difference_ms_per_step": round(med["worker"]["wall_ms_per_step"] - med["in-process"]["wall_ms_per_step"], 4),
        "worker_setup_s": round(med["worker"]["setup_s"] - med["in-process"]["setup_s"], 3),
        "cores": os.cpu_count(), "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(), "load_average_before": round(load_before, 2),
        "load_average_after": round(os.getloadavg()[0], 2)}
    if with_fish:
        doc["paper_dump"] = {p: measure(scenario, p, {}) for p in ("in-process", "worker")}
    return doc


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    ip, w = doc["in_process"], doc["worker"]
    lines = [f"{doc['fmus']} FMUs, {doc['steps']} steps, median of {doc['repeats']}: FMU stage "
             f"{ip['fmu_ms_per_step']:.3f} ms/step in-process, {w['fmu_ms_per_step']:.3f} ms/step in workers: isolation "
             f"costs {doc['isolation_ms_per_step']:.3f} ms per step ({doc['isolation_ms_per_fmu_step']:.3f} ms per FMU "
             f"and step), start-up {doc['worker_setup_s']:.2f} s"]
    for p, r in doc.get("paper_dump", {}).items():
        lines.append(f"paper test as shipped, {p}: {r['wall_ms_per_step']:.2f} ms/step ({r['steps']} steps, "
                     f"FMU stage {r['fmu_ms_per_step']:.3f} ms/step)")
    return lines
