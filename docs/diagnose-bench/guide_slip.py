"""What the benchmark's datasets carry of guide wear, read as its candidate reads them (measured data alone, no
simulation): per dataset and belt, the fish touching a side guide (rows of `guide_rows`: a fish on a 0.25 m stretch
of a belt) and their mean slip beyond the fish clear of the guides on the same belt, with the candidate's test
(`fishfmu.analysis.causes.guide`, seed 0).  Datasets whose truth has guide wear are marked; the others are the
range a worn guide must leave.

    python docs/diagnose-bench/guide_slip.py DATASET... > FILE
"""

import argparse
import json
from pathlib import Path

import numpy as np

from plant.contract.measured import read_dataset

from fishfmu.analysis.causes import guide
from fishfmu.analysis.observations import guide_rows


def belt_table(rows) -> dict[str, tuple[int, float]]:
    """Per belt: (rows touching a guide, their mean slip less that of the fish clear of the guides), m/s."""
    out = {}
    for belt, part in rows.groupby("conveyor_id"):
        touching, clear = part[part["touching"] == 1.0], part[part["touching"] == 0.0]
        excess = float(touching["slip_mps"].mean() - clear["slip_mps"].mean()) if len(touching) and len(clear) else np.nan
        out[str(belt)] = (int(len(touching)), excess)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    args = parser.parse_args()
    lines = ["dataset | wear | touching rows c1/c2/c3/c4 | touching less clear, mean slip c1/c2/c3/c4 [cm/s] | test p, "
             "effect [cm/s]"]
    print(lines[0], flush=True)
    for path in args.datasets:
        truth = path.with_name(path.name + ".truth.json")
        effects = json.loads(truth.read_text()).get("effects", []) if truth.exists() else []
        rows = guide_rows(read_dataset(path, check_physics=False))
        test = guide.test({"guides": rows}, np.random.default_rng(0))
        table = belt_table(rows)
        belts = ["c1", "c2", "c3", "c4"]
        counts = "/".join(str(table.get(b, (0, np.nan))[0]) for b in belts)
        excess = "/".join("-" if np.isnan(table.get(b, (0, np.nan))[1]) else f"{100 * table[b][1]:+.1f}" for b in belts)
        p = f"{test.p_value:.3f}" if test.judged else "not judged"
        lines.append(f"{path.name} | {'yes' if 'guide_friction_wear' in effects else 'no'} | {counts} | {excess} | "
                     f"{p}, {100 * test.effect:.2f}")
        print(lines[-1], flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
