"""The mucus candidate's test on measured drops alone, judged by its shuffle of rows and by hours shuffled between
runs (docs/diagnosis.md, "Mucus fitted on the drops").  Not part of the product: a measurement beside the benchmark.
Needs no simulation (the test reads the measured slips):

    python docs/diagnose-bench/mucus_shuffle.py DATASET [DATASET ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from plant.contract.measured import read_dataset

from fishfmu.analysis import covariates
from fishfmu.analysis.causes import mucus
from fishfmu.analysis.observations import drop_rows


def test_shuffling(shuffle: str):
    """``covariates.covariate_test`` with the shuffle replaced (the candidate's test names its own)."""
    def run(candidate, quantity, covariate, design, _, rng, *args, **kwargs):
        return covariates.covariate_test(candidate, quantity, covariate, design, shuffle, rng, *args, **kwargs)
    return run


def main() -> None:
    for path in map(Path, sys.argv[1:]):
        rows = {"drops": drop_rows(read_dataset(path))}
        p = {}
        for shuffle in ("rows", "between"):
            mucus.covariate_test = test_shuffling(shuffle)  # the module's own name for it, replaced for this call
            p[shuffle] = mucus.test(rows, np.random.default_rng(0)).p_value
        print(f"{path.name}: rows p {p['rows']:.4f}; between runs p {p['between']:.4f}", flush=True)


if __name__ == "__main__":
    main()
