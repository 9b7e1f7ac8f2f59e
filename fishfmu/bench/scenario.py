"""Speed of whole scenarios as a user runs them: simulated seconds per second of wall time and per
CPU second of the whole process, where the time goes, fish in play over time, peak memory.

    fishfmu bench scenario scenarios/paper_dump.toml scenarios/continuous.toml --repeats 2

Each case runs in a fresh Python process, as ``fishfmu run --no-report`` does (imports, checks,
FMUs, the run, its files written to a temporary folder), so that CPU time and peak memory are those
of one run and include everything the process did; the master's stages are timed by its
:class:`~fishfmu.cosim.master.StageClock`.  Fish in play at a time are those with a track sample then
(on the line: dropped and not yet gone).
"""

from __future__ import annotations

import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from plant.errors import SimulationError

from fishfmu import commands
from fishfmu.cosim.master import StageClock


def run_case(scenario: str | Path, overrides: dict[str, Any]) -> dict[str, Any]:
    """One run of ``scenario`` in this process (call it in a fresh one, see :func:`bench`)."""
    clock = StageClock()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fishfmu-bench-") as tmp:
        done = commands.run(scenario, Path(tmp) / "out", overrides, report=False, clock=clock)
    wall_s = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu_s = usage.ru_utime + usage.ru_stime
    result = done.result
    if result.status != "ok":
        raise SimulationError(f"benchmark run of {scenario} ended {result.status}: {result.error}")
    tracks = result.run.tracks
    in_play = tracks.groupby("t_s")["fish_id"].nunique() if len(tracks) else None
    sim_s = result.t_end_s
    rec = {
        "scenario": str(scenario), "overrides": overrides, "simulated_s": sim_s,
        "process_cpu_s": round(cpu_s, 3), "process_wall_s": round(wall_s, 3), "run_wall_s": round(result.wall_s, 3),
        "rtf_cpu": round(sim_s / cpu_s, 3), "rtf_wall": round(sim_s / wall_s, 3),
        "stages_s": {k: round(v, 3) for k, v in clock.totals_s.items()},
        "comm_step_s": result.scenario.run.comm_step_s,
        "plant_exudyn_s": round(result.timings_s.get("plant_exudyn", 0.0), 3),
        "plant_rebuild_s": round(result.timings_s.get("plant_rebuild", 0.0), 3),
        "plant_rebuild_longest_ms": round(1e3 * result.timings_s.get("plant_rebuild_longest", 0.0), 2),
        "fish": len(result.fish), "fish_in_play_mean": round(float(in_play.mean()), 2) if in_play is not None else 0.0,
        "fish_in_play_max": int(in_play.max()) if in_play is not None else 0,
        "fish_in_play_per_s": ({f"{t:g}": int(n) for t, n in in_play.groupby(in_play.index.astype(int)).max().items()}
                               if in_play is not None else {}),
        "peak_rss_mb": round(usage.ru_maxrss / 1024.0, 1), "kpis": {k: v for k, v in result.kpis.items()
                                                                    if isinstance(v, (int, float))}}
    rec["cpu_per_step_ms"] = cpu_per_step_ms(rec)
    return rec


def bench(scenarios: list[str | Path], repeats: int = 1, overrides: dict[str, Any] | None = None,
          on_record=None) -> dict[str, Any]:
    """Each scenario ``repeats`` times, each run in a fresh process; the median per scenario."""
    overrides = overrides or {}
    runs: dict[str, list[dict[str, Any]]] = {str(s): [] for s in scenarios}
    load_before = os.getloadavg()[0]
    for _ in range(repeats):
        for s in scenarios:  # interleaved: a change of machine load hits every scenario alike
            proc = subprocess.run([sys.executable, "-m", "fishfmu.bench.scenario", str(s), json.dumps(overrides)],
                                  capture_output=True, text=True)
            if proc.returncode != 0:
                raise SimulationError(f"benchmark run of {s} failed:\n{proc.stderr[-2000:]}")
            rec = json.loads(proc.stdout.strip().splitlines()[-1])
            runs[str(s)].append(rec)
            if on_record is not None:
                on_record(rec)
    median = {s: {k: statistics.median(r[k] for r in rs) for k in ("rtf_cpu", "rtf_wall", "process_cpu_s",
                                                                      "simulated_s", "peak_rss_mb")}
              for s, rs in runs.items()}
    return {"runs": runs, "median": median, "repeats": repeats, "cores": os.cpu_count(),
            "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
            "load_average_before": round(load_before, 2), "load_average_after": round(os.getloadavg()[0], 2)}


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    lines = []
    for s, m in doc["median"].items():
        last = doc["runs"][s][-1]
        stages = last["stages_s"]
        total = sum(stages.values()) or 1.0
        lines.append(f"{Path(s).stem}: {m['simulated_s']:.1f} s simulated, {m['rtf_cpu']:.2f}x real time per CPU s "
                     f"of the whole process ({m['rtf_wall']:.2f}x per wall s), median of {doc['repeats']}; "
                     f"fish in play {last['fish_in_play_mean']:.1f} on average, {last['fish_in_play_max']} at most; "
                     f"peak {m['peak_rss_mb']:.0f} MB; stages: "
                     + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in stages.items()))
        lines.append("  CPU per communication step: " + ", ".join(
            f"{k} {v:.2f} ms" for k, v in last["cpu_per_step_ms"].items())
            + f"; the longest rebuild {last.get('plant_rebuild_longest_ms', 0.0):.1f} ms")
    return lines


def cpu_per_step_ms(rec: dict[str, Any]) -> dict[str, float]:
    """Where one run's time went, per communication step [ms]: Exudyn's integration, rebuilding the
    system, the plant's own Python (sensors, joints, checks), the FMUs, the rest of the master's step
    (energy check, recording, events), and everything outside the steps (imports, checks, start-up,
    files) spread over them."""
    stages = rec["stages_s"]
    steps = max(1, round(rec["simulated_s"] / rec.get("comm_step_s", 0.01)))
    loop_s = sum(stages.values())
    exudyn, rebuild = rec.get("plant_exudyn_s", 0.0), rec.get("plant_rebuild_s", 0.0)
    parts = {"exudyn": exudyn, "rebuild": rebuild, "plant_python": stages.get("plant", 0.0) - exudyn - rebuild,
             "fmus": stages.get("fmus", 0.0), "master_rest": loop_s - stages.get("plant", 0.0) - stages.get("fmus", 0.0),
             "outside_steps": max(0.0, rec["process_cpu_s"] - loop_s)}
    return {k: round(1e3 * v / steps, 3) for k, v in parts.items()}


if __name__ == "__main__":  # one case, used by bench()
    print(json.dumps(run_case(sys.argv[1], json.loads(sys.argv[2]))))
