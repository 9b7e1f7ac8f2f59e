"""Adhesion: a force between fish in contact (slime holds touching fish together).

Signature: touching pairs side by side when the leading one crosses a transfer: how much of the belts' speed
difference their separation gained, against the touching pairs of the same runs re-simulated with the constant
model (no force between fish beyond contact and friction); with adhesion the measured ones part less (sign -1).
Extension: ``force_n`` per pair of touching contact spheres, fitted on a grid of simulated strengths on the runs
with touching pairs, and scored on how far each run's pairs part on the whole (the ``pair_levels`` group: the mean of
their extra separation as a share of the belts' speed difference), not pair by pair: a pile's chaos decides which
pair parts, the force how many.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, against_model, covariate_test
from fishfmu.analysis.extension_fit import fit_on_grid


def apply(p: PlantParams, force_n: float) -> None:
    p.extensions.adhesion.force_n = force_n


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.adhesion.force_n = 6.0 * s


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """Touching pairs of the measured runs against those of the same runs re-simulated, compared within each run by
    rank (:func:`~fishfmu.analysis.covariates.against_model`); held together, the measured ones rank lower."""
    pairs, model_pairs = rows["pairs"], rows.get("model_pairs")
    quantity = "rank within its run of the share of the belts' speed difference a touching pair's separation gained"
    covariate = "contact between the fish (measured against the model)"
    if model_pairs is None:
        out = CovariateTest("adhesion", quantity, covariate, 0, 0)
        out.note = "no re-simulation of the runs to compare the pairs with"
        return out
    touching = [p[p["touching"] == 1.0] for p in (pairs, model_pairs)]
    d = against_model(*touching, "growth", sign=-1)
    return covariate_test("adhesion", quantity, covariate, d, "within", rng)


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """The force pulling a touching pair of contact spheres together [N]."""
    return {"bond_force_n": float(values.get("force_n", 0.0))}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: touching pairs' separation, measured against the model."""
    pairs, model = rows.get("pairs"), rows.get("model_pairs")
    parts = [g[g["touching"] == 1.0]["growth"].to_numpy(float) for g in (pairs, model) if g is not None]
    if parts and any(len(p) for p in parts):
        ax.boxplot(parts, tick_labels=["measured", "model"][:len(parts)])
    ax.set(ylabel="touching pairs: separation gained\n/ belts' speed difference")


CANDIDATE = Candidate(
    "adhesion", "attraction per pair of touching contact spheres", ("force_n",), "N", 0.0, (2.0, 6.0), (0.0, 50.0),
    "plant", apply, ("extensions.adhesion.force_n",), test=test,
    decides="more batches dumped onto the infeed, with fish side by side both touching and with a gap",
    fit=fit_on_grid, groups=("pair_levels",), synthetic=hide, terms=terms, primary="bond_force_n",
    explains=(("pairs", "touching"),), plot=plot)
