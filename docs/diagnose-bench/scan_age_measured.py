"""The scan's tests of age in monotone shapes (``hours_monotone``) on the quantities read as measured, without the
calibration's re-simulation (the transfers' lags need it and are left out): on each dataset given, the tests that
would be findings at the threshold a full diagnosis holds them to (0.02 over its number of tests), and the smallest
p-value of them with its held-out gain.  A check of the scan's false alarms on no-effect datasets in seconds a
dataset (docs/diagnosis.md).

    python docs/diagnose-bench/scan_age_measured.py --threshold 0.00054 DATASET... > FILE
"""

import argparse
from pathlib import Path

import numpy as np

from plant.contract.measured import read_dataset

from fishfmu.analysis.scan import scan
from fishfmu.analysis.scan_tables import scan_tables
from fishfmu.analysis.signatures import ALPHA, judge


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threshold", type=float, required=True, help="a finding's p-value at most this")
    parser.add_argument("datasets", nargs="+", type=Path)
    args = parser.parse_args()
    for path in args.datasets:
        ds = read_dataset(path)
        j = judge(ds, np.random.default_rng(0), None)  # the measured rows only: no re-simulation
        found = scan(scan_tables(ds, j.rows, []), np.random.default_rng((0, 41)), set(), ALPHA)
        age = [(q.table, t) for q, _, key, t in found.tests if key == "hours_monotone" and t.judged]
        hits = [f"{table} p {t.p_value:.4f} gain {t.heldout_gain:.3f} ({t.shape})" for table, t in age
                if t.p_value <= args.threshold and t.heldout_gain > 0.0 and t.effect >= t.min_effect]
        table, best = min(age, key=lambda a: a[1].p_value) if age else ("-", None)
        smallest = f"{table} p {best.p_value:.4f} gain {best.heldout_gain:.3f}" if best else "no test"
        print(f"{path.name:28} findings: {'; '.join(hits) or 'none'}; smallest p: {smallest}", flush=True)


if __name__ == "__main__":
    main()
