"""What one rebuild of the Exudyn system costs: the continuous line alone and with eight fish (the fish in its
system at a time), the best of five builds each, and the solver's initialisation.  A rebuild comes whenever fish are
admitted before their drop or enough have left; served in real time it is that much time at once:

    .venv/bin/python docs/speed-bench/rebuild.py --json bench-results/rebuild.json
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from plant.errors import InputError
from plant.fish.extensions import highest_body_level
from plant.fish.fish_body import FISH_MODELS
from plant.sim import model, system
from plant.sim.surfaces import line_surfaces

from fishfmu import commands
from fishfmu.cosim.build import scenario_fish
from fishfmu.scenario.schema import load_scenario


def best_ms(build, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        build()
        times.append(time.perf_counter() - t0)
    return round(1e3 * min(times), 2)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="scenarios/continuous.toml")
    parser.add_argument("--fish", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    try:
        commands.check_targets(Path(args.json) if args.json else None)
    except InputError as exc:  # a file fishfmu did not write: never replaced
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sc = load_scenario(args.scenario)
    params, line, gravity = sc.plant, sc.line, np.array([0.0, 0.0, -sc.plant.gravity_mps2])
    fish = scenario_fish(sc)[:args.fish]
    parks = model.park_positions(line, len(fish))
    members = [model.parked_member(i, model.prepare_fish(f, params), parks[i], 80) for i, f in enumerate(fish)]
    surfaces = line_surfaces(line, params.guide_height_m)
    # the friction table as the plant gives it: up to the fish's level, all levels with directional friction
    top = None if params.extensions.direction_friction.on else highest_body_level(
        [80] * len(members), params.friction.belt_gradient, FISH_MODELS[params.fish_model])
    figures = {"scenario": args.scenario, "fish": len(fish), "repeats": args.repeats,
               "line_alone_ms": best_ms(lambda: system.build_model(surfaces, [], params, gravity, line, top),
                                        args.repeats),
               "with_fish_ms": best_ms(lambda: system.build_model(surfaces, members, params, gravity, line, top),
                                       args.repeats)}
    built = system.build_model(surfaces, members, params, gravity, line, top)

    def initialise() -> None:
        solver = model.exu.MainSolverExplicit()
        built.settings.timeIntegration.endTime = 1.0e6
        built.settings.timeIntegration.numberOfSteps = int(1.0e6 / params.numerics.step_s)
        solver.InitializeSolver(built.mbs, built.settings)
    figures["initialise_solver_ms"] = best_ms(initialise, args.repeats)
    print(json.dumps(figures))
    if args.json:  # replaced only if fishfmu wrote it, as every benchmark's file
        commands.write_json(Path(args.json), figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
