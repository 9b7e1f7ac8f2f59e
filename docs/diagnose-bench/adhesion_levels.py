"""Adhesion's held-out gain scored pair by pair and as each run's level, on the same simulations (issue 40).

Beside the benchmark, not part of the product. Runs ``fishfmu diagnose`` on a dataset keeping the simulations of
every extension fitted on a grid (``OUT.grids/NAME.pkl``), then scores adhesion's grid both ways with the product's
cross-validation (``grid_fit``: folds over runs, the strength nearest the vertex of the other folds' error):

- ``per pair``: the sum of squares of every touching pair's extra separation [m] (the score before 2026-11-29);
- ``run level``: each run's pairs as one level, the mean extra separation as a share of how far the belts part them
  (``RunResiduals.pair_level``, the score since).

    python docs/diagnose-bench/adhesion_levels.py DATASET OUT [--workers 2]   # diagnose, then score
    python docs/diagnose-bench/adhesion_levels.py DATASET OUT --score-only    # score a kept OUT.grids
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from fishfmu.analysis import extension_fit
from fishfmu.analysis.candidates import CANDIDATES


def keep_grids(dump: Path) -> None:
    """Wrap ``grid_fit`` so that every grid it scores is kept in ``dump``."""
    fit = extension_fit.grid_fit

    def grid_fit(cand, base, grid, rng):
        with open(dump / f"{cand.name}.pkl", "wb") as fh:
            pickle.dump({"name": cand.name, "base": base, "grid": grid}, fh)
        return fit(cand, base, grid, rng)

    extension_fit.grid_fit = grid_fit


def with_parting(g: dict, dataset: str) -> dict:
    """Tables kept by a checkout from before ``parting_m`` (commit 7c0fe25): the column added as
    ``pair_residuals`` computes it now, from the dataset's belt logs."""
    from plant.contract.measured import read_dataset
    ds = read_dataset(dataset)
    conveyors = ds.line.conveyors
    parting = {}
    for run in ds.runs:
        speed = {c.id: float(run.belts.loc[run.belts["conveyor_id"] == c.id, "speed_mps"].median()) for c in conveyors}
        for k, c in enumerate(conveyors[1:], start=1):
            dv = speed[c.id] - speed[conveyors[k - 1].id]
            parting[(run.id, c.id)] = dv * 1.5 if dv >= 0.05 else float("nan")
    for table in [g["base"], *g["grid"].values()]:
        for rr in table.values():
            if "parting_m" not in rr.pairs:
                rr.pairs = rr.pairs.assign(parting_m=[parting[(rr.run_id, c)] for c in rr.pairs["conveyor_id"]])
    return g


def score(kept: Path, dataset: str) -> None:
    g = with_parting(pickle.loads(kept.read_bytes()), dataset)
    adhesion = CANDIDATES["adhesion"]
    for label, groups in (("per pair", ("pairs",)), ("run level", ("pair_levels",))):
        cand = adhesion.__class__(**{**adhesion.__dict__, "groups": groups})
        fit = extension_fit.grid_fit(cand, g["base"], g["grid"], np.random.default_rng(0))
        lo, hi = fit.heldout_gain_ci95
        print(f"{kept.parent.name[:-len('.grids')]}  {label:9s}  gain {100 * fit.heldout_gain:6.1f} % "
              f"[{100 * lo:6.1f}, {100 * hi:6.1f}]  confirmed {fit.confirmed!s:5s}  force {fit.values['force_n']:.2f} N "
              f"(searched {', '.join(f'{v:g}' for v in sorted(g['grid']))})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset")
    ap.add_argument("out")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--score-only", action="store_true")
    a = ap.parse_args()
    dump = Path(a.out + ".grids")
    if not a.score_only:
        dump.mkdir(parents=True, exist_ok=True)
        keep_grids(dump)
        from fishfmu import commands
        commands.diagnose(a.dataset, a.out, workers=a.workers, progress=lambda s: print(s, flush=True))
    if (dump / "adhesion.pkl").exists():
        score(dump / "adhesion.pkl", a.dataset)
    else:
        print(f"{a.dataset}: adhesion was not fitted (not named)")


if __name__ == "__main__":
    main()
