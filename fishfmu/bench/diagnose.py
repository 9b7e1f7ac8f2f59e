"""Benchmark of ``diagnose`` on hidden effects: how often it names the right cause, over many seeds.

    python -m fishfmu.bench.diagnose --seeds 5 --json bench-results/diagnose_bench.json

Each effect (and none) is simulated on the small line and run design of ``fishfmu.analysis.synthetic`` (that of tests/test_diagnose.py) with
a different seed per repetition (different fish, drops, noise), diagnosed without being told, and
the named cause recorded; the result is a confusion table and the accuracy per effect.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import pandas as pd

from plant.measured import read_dataset

from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.synthetic import EFFECTS, SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset

def run_bench(seeds: list[int], effects: tuple[str, ...] = EFFECTS, strength: float = 1.0, workers: int = 2) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        for effect in effects:
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                path = make_dataset(Path(tmp) / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS,
                                    seed=seed, strength=strength)
                d = diagnose(read_dataset(path), workers=workers, seed=seed)
                fit = next((f for f in d.fits if f.name == d.cause), None)
                rows.append({"effect": effect, "seed": seed, "cause": d.cause, "correct": d.cause == effect,
                             "heldout_gain": fit.heldout_gain if fit else 0.0, "wall_s": time.perf_counter() - t0})
                print(rows[-1], flush=True)
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--strength", type=float, default=1.0)
    ap.add_argument("--json", type=Path, default=Path("bench-results/diagnose_bench.json"))
    args = ap.parse_args()
    table = run_bench(list(range(args.first_seed, args.first_seed + args.seeds)), strength=args.strength)
    confusion = pd.crosstab(table["effect"], table["cause"])
    accuracy = table.groupby("effect")["correct"].mean()
    print(confusion.to_string())
    print(accuracy.to_string())
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": table.to_dict(orient="records"),
                                     "accuracy": accuracy.to_dict(), "overall": float(table["correct"].mean()),
                                     "confusion": confusion.to_dict(), "strength": args.strength}, indent=2))


if __name__ == "__main__":
    main()
