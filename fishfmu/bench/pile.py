"""Benchmark: real-time factor of the plant alone and of the whole co-simulation, where the time goes,
the cost of a communication step with no fish and per fish, and peak memory.

Each fish count runs in its own Python process, so timings do not share caches or warm-ups and the
peak resident memory (``ru_maxrss``) is that of one case.  A case is the paper's line with an infeed
long enough to hold the batch, the paper scenario's FMUs (controller and four drives) for the
co-simulation, fish dumped onto the running infeed; the clock runs over ``duration_s`` simulated
seconds after the last fish has been dropped and has landed (1 s).

Real-time factor = simulated seconds per wall-clock second (larger is faster).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from plant.errors import SimulationError
from plant.sim.plant import Plant

from fishfmu.cosim.build import build, checked, scenario_fish
from fishfmu.cosim.master import StageClock
from fishfmu.output.atomic import write_figure_atomic
from fishfmu.scenario.schema import load_scenario

PAPER = Path(__file__).parents[2] / "scenarios" / "paper_dump.toml"


@dataclass
class BenchRecord:
    fish: int
    threads: int
    comm_step_s: float
    duration_s: float
    rtf_plant: float
    """Plant alone (belts at constant speed), simulated s per wall s."""
    rtf_cosim: float
    """Plant, FMUs and master, simulated s per wall s."""
    plant_exudyn_s: float
    """Co-simulation: wall time in Exudyn's solver over the measured window."""
    plant_python_s: float
    """Co-simulation: the plant's own work around the solver (sensors, joints, drops, rebuilds)."""
    fmu_s: float
    """Co-simulation: stepping the FMUs (their inputs routed and set, doStep, outputs read)."""
    master_s: float
    """Co-simulation: the master's own work outside the FMUs (events, belt speeds)."""
    recording_s: float
    """Co-simulation: the step observers (energy watch, fish counts, recording tracks and belt logs) and the signals."""
    wall_cosim_s: float
    step_cost_ms: float
    """Plant alone: wall time of one communication step, averaged over the window."""
    peak_rss_mb: float

    @property
    def overhead_fraction(self) -> float:
        return (self.fmu_s + self.master_s + self.recording_s) / self.wall_cosim_s if self.wall_cosim_s else 0.0


def bench_scenario(n_fish: int, comm_step_s: float, threads: int):
    """The paper scenario scaled to n fish: an infeed long enough to hold them (the belts after it as in
    the paper's line, shifted), fish dumped onto it once it runs."""
    sc = load_scenario(PAPER)
    infeed = max(2.0, 0.12 * n_fish)
    shift = infeed - sc.line.conveyors[0].length_m
    data = sc.model_dump(mode="python")
    data["line"]["conveyors"][0]["length_m"] = infeed
    for c in data["line"]["conveyors"][1:]:
        c["x_start_m"] += shift
    for p in data["line"]["photoeyes"]:
        p["x_m"] += shift
    data["fish"].update(count=max(n_fish, 1), drop_interval_s=min(0.25, 4.0 / max(n_fish, 1)), drop_x_min_m=0.0,
                        drop_x_max_m=0.9 * infeed)
    data["run"].update(comm_step_s=comm_step_s, stop_when_clear=False)
    data["plant"]["numerics"]["threads"] = threads
    data["expect"] = {}
    return type(sc).model_validate(data)


def run_case(n_fish: int, duration_s: float, comm_step_s: float, threads: int) -> BenchRecord:
    """Measure one fish count in this process (see the module docstring)."""
    sc = bench_scenario(n_fish, comm_step_s, threads)
    fish = scenario_fish(sc) if n_fish else []  # 0 fish: the cost of the line alone
    t_start = (max(f.drop_t_s for f in fish) if fish else 0.0) + 1.0
    n_warm = int(round(t_start / comm_step_s))
    n_meas = int(round(duration_s / comm_step_s))
    speeds = {"c1": 0.25, "c2": 0.5, "c3": 0.8, "c4": 1.25}

    # plant alone
    plant = Plant(sc.line, fish, sc.plant, comm_step_s)
    for _ in range(n_warm):
        plant.step(speeds)
    t0 = time.perf_counter()
    for _ in range(n_meas):
        plant.step(speeds)
    wall_plant = time.perf_counter() - t0

    # co-simulation, built as a run builds it, its stages timed by the master's clock
    clock = StageClock()
    with checked(sc) as c, build(c, fish, clock=clock) as cosim:
        for _ in range(n_warm):
            cosim.step()
        clock.reset()
        exu0 = cosim.plant.state.timings_s["exudyn"]
        t0 = time.perf_counter()
        for _ in range(n_meas):
            cosim.step()
        wall_cosim = time.perf_counter() - t0
        exudyn = cosim.plant.state.timings_s["exudyn"] - exu0
    stages = clock.totals_s
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return BenchRecord(
        fish=n_fish, threads=threads, comm_step_s=comm_step_s, duration_s=duration_s,
        rtf_plant=duration_s / wall_plant, rtf_cosim=duration_s / wall_cosim,
        plant_exudyn_s=exudyn, plant_python_s=stages["plant"] - exudyn, fmu_s=stages["fmus"],
        master_s=stages["events"] + stages["belt_speeds"], recording_s=stages["observers"] + stages["signals"],
        wall_cosim_s=wall_cosim, step_cost_ms=1e3 * wall_plant / n_meas, peak_rss_mb=peak_mb)


def run_bench(fish_counts: list[int], duration_s: float = 5.0, comm_step_s: float = 0.01,
              threads: int = 1, on_record=None) -> list[BenchRecord]:
    """Each fish count in a fresh process; returns the records in order."""
    out = []
    for n in fish_counts:
        proc = subprocess.run([sys.executable, "-m", "fishfmu.bench.pile", str(n), str(duration_s), str(comm_step_s),
                               str(threads)], capture_output=True, text=True)
        if proc.returncode != 0:
            raise SimulationError(f"benchmark case with {n} fish failed:\n{proc.stderr[-2000:]}")
        rec = BenchRecord(**json.loads(proc.stdout.strip().splitlines()[-1]))
        out.append(rec)
        if on_record is not None:
            on_record(rec)
    return out


def per_fish_cost(records: list[BenchRecord]) -> tuple[float, float]:
    """(ms per step with no fish, ms per step per fish): a straight line through (fish, step cost)."""
    n = np.array([r.fish for r in records], dtype=float)
    c = np.array([r.step_cost_ms for r in records])
    if len(n) < 2:
        return float(c[0]) if len(c) else 0.0, 0.0
    slope, intercept = np.polyfit(n, c, 1)
    return float(intercept), float(slope)


def plot(records: list[BenchRecord], path: Path) -> None:
    # slow and optional: matplotlib, only for --plot
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # slow and optional: matplotlib, after choosing its file-only backend
    fig, ax = plt.subplots(figsize=(6, 3.5))
    n = [r.fish for r in records]
    ax.plot(n, [r.step_cost_ms for r in records], "o-", label="plant alone")
    ax.plot(n, [1e3 * r.wall_cosim_s / (r.duration_s / r.comm_step_s) for r in records], "s-", label="co-simulation")
    ax.set_xlabel("fish on the line")
    ax.set_ylabel("wall time per 10 ms step [ms]")
    ax.axhline(1e3 * records[0].comm_step_s, color="k", lw=0.8, ls=":", label="real time")
    ax.legend()
    ax.grid(alpha=0.3)
    try:
        write_figure_atomic(path, fig, dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)


def records_json(records: list[BenchRecord]) -> list[dict]:
    return [dict(asdict(r), overhead_fraction=r.overhead_fraction) for r in records]


if __name__ == "__main__":  # one case, used by run_bench
    n, dur, dt, th = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
    print(json.dumps(asdict(run_case(n, dur, dt, th))))
