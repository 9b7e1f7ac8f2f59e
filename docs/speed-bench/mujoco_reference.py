"""The reference our speed is measured against: the independent simulator's (MuJoCo) dumped batch.

Runs in the independent simulator's own environment (never in fishfmu's: the product does not import
it), one run per seed of its default design (18 fish dropped within 4-8 s, implicit integrator),
and writes simulated seconds per CPU second of the run and of the whole process:

    /tmp/linesim-venv/bin/python docs/speed-bench/mujoco_reference.py --linesim ../shared/linesim \
        --seeds 1 2 3 --json bench-results/mujoco_reference.json
"""

import argparse
import json
import resource
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--linesim", required=True, help="the independent simulator's folder")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--fish", type=int, default=18)
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    sys.path.insert(0, args.linesim)
    import gen  # the simulator's own entry point: its base physics and default design, unchanged
    from emu.effects import BASE

    runs = []
    for seed in args.seeds:
        result = gen.simulate_run((seed, 0, "none", {}, dict(BASE), 6.0, args.fish, None, {}))
        runs.append({"seed": seed, "simulated_s": float(result["t_end"]), "cpu_s": float(result["cpu_s"]),
                     "dt_s": float(result["dt_used"]), "lost": len(result["lost"])})
        print(f"seed {seed}: {runs[-1]['simulated_s']:.1f} s simulated in {runs[-1]['cpu_s']:.2f} CPU s "
              f"= {runs[-1]['simulated_s'] / runs[-1]['cpu_s']:.2f}x (step {runs[-1]['dt_s'] * 1e3:g} ms)")
    process_cpu_s = time.process_time()
    simulated_s = sum(r["simulated_s"] for r in runs)
    summary = {"runs": runs, "rtf_per_run_cpu_s": simulated_s / sum(r["cpu_s"] for r in runs),
               "rtf_per_process_cpu_s": simulated_s / process_cpu_s,
               "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    print(f"MuJoCo reference: {summary['rtf_per_run_cpu_s']:.2f}x per CPU s of the runs, "
          f"{summary['rtf_per_process_cpu_s']:.2f}x per CPU s of the process")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
