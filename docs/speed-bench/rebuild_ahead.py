"""What each rebuild of a run's plant costs, built whole and with its system laid out ahead (`Plant.build_ahead`
after every step, given all the time it takes, as a served run gives it what its steps leave over): the plant
alone with the scenario's fish and fixed belt speeds, one run each way, and whether the two end the same to the bit:

    .venv/bin/python docs/speed-bench/rebuild_ahead.py [--scenario scenarios/paper_dump.toml] [--json FILE]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from plant.errors import InputError
from plant.sim.plant import Plant

from fishfmu import commands
from fishfmu.cosim.build import scenario_fish
from fishfmu.scenario.schema import load_scenario


def run(sc, speeds: list[float], steps: int, ahead: bool) -> tuple[list[dict], np.ndarray]:
    """(each rebuild: time, fish in the new system, wall ms), the bodies' final positions."""
    plant = Plant(sc.line, scenario_fish(sc), sc.plant, sc.run.comm_step_s, seed=sc.run.seed)
    rebuilds, rebuild = [], plant._rebuild  # timed from outside: the plant's own timer sums them

    def timed(t: float) -> None:
        t0 = time.perf_counter()
        rebuild(t)
        rebuilds.append({"t_s": round(plant.t_s, 2), "fish": len(plant.model.fish),
                         "ms": round(1e3 * (time.perf_counter() - t0), 2)})

    plant._rebuild = timed
    belts = {c.id: v for c, v in zip(sc.line.conveyors, speeds)}
    for _ in range(steps):
        plant.step(belts)
        if ahead:
            plant.build_ahead(1.0)
    return rebuilds, plant.state.pos.copy()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="scenarios/paper_dump.toml")
    parser.add_argument("--speeds", default="0.25,0.5,0.8,1.25", help="each belt's speed, m/s")
    parser.add_argument("--steps", type=int, default=2300, help="communication steps (2300: the dumped batch leaves)")
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    try:
        commands.check_targets(Path(args.json) if args.json else None)
    except InputError as exc:  # a file fishfmu did not write: never replaced
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sc = load_scenario(args.scenario)
    steps = args.steps
    speeds = [float(v) for v in args.speeds.split(",")]
    whole, pos_whole = run(sc, speeds, steps, ahead=False)
    ahead, pos_ahead = run(sc, speeds, steps, ahead=True)
    figures = {"scenario": args.scenario, "steps": steps, "whole": whole, "ahead": ahead,
               "same_to_the_bit": bool(pos_whole.shape == pos_ahead.shape and np.array_equal(pos_whole, pos_ahead))}
    print(json.dumps(figures))
    if args.json:  # replaced only if fishfmu wrote it, as every benchmark's file
        commands.write_json(Path(args.json), figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
