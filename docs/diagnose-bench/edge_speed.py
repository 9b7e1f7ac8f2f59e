"""The unexplained-discrepancy scan's photo-eye edges against each fish's own tracked speed at the edge, beside the
belt's logged speed the scan offers (docs/diagnosis.md, "A fish's own speed at the eye, tried as a scan covariate").
Not part of the product: a measurement beside the benchmark. Needs no simulation (the edges are read as measured):

    python docs/diagnose-bench/edge_speed.py DATASET [DATASET ...]

One line a dataset: each covariate's test as the scan runs it (its design, shuffle and permutations; seed 41), with
its p-value, held-out gain, effect over the data's range and the shape it chose.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from plant.contract.measured import read_dataset

from fishfmu.analysis import scan
from fishfmu.analysis.observations import edge_rows

FISH_SPEED = scan.Covariate("speed_mps", "the fish's own speed at the edge (tracked)", "speed_mps",
                            scan._linear("speed [m/s]"), "fish")
"""Varies among the fish of a run: each run (at each eye) its own level, the speeds shuffled within runs."""


def main() -> None:
    edges = next(q for q in scan.QUANTITIES if q.table == "edges")
    for path in map(Path, sys.argv[1:]):
        rows = edge_rows(read_dataset(path))
        out = {}
        for cov in (FISH_SPEED, scan.COVARIATES["belt_speed_mps"]):
            made = scan._design(edges, cov, rows, pooled=True)
            if made is None:
                out[cov.key] = None
                continue
            t = scan._test("edges", edges, cov, *made, np.random.default_rng(41), deciding=True)
            out[cov.key] = {"p": t.p_value, "heldout_gain": round(t.heldout_gain, 3), "effect_m": round(t.effect, 4),
                            "shape": t.shape}
        print(path.name, json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
