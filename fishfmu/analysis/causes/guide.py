"""Guide wear: fish-guide friction rises along the line (guide liners worn rough, or caked with dried slime and
scales, where the fish run fast).

Signature: the slip of fish touching a side guide (their belt's logged speed less theirs, per stretch of belt)
against their position along the line, beyond what the same stretch does to fish clear of the guides.  With one
fish-guide friction a fish pressed against a guide is held back the same wherever it is; whatever a stretch of belt
does to every fish on it (a slippery zone, a belt's own speed error) is one level per stretch, and guide contact as
such is one more level; only a guide that grips harder downstream makes the touching fish's slip grow with x (sign
+1).  Extension: ``guide_wear``, the guides in 0.2 m sections whose friction rises linearly to (1 + rise) x the
infeed's at the outfeed end, fitted on a grid of simulated strengths on the runs with fish touching a guide.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test, robust
from fishfmu.analysis.extension_fit import CandidateFit, FitContext, fit_on_grid
from fishfmu.analysis.observations import guide_rows

MIN_SLIP_MPS = 0.01
"""Named only if the slip of a fish at a guide grows by at least 1 cm/s from one end of the line to the other: a fish
held back so much for the 2-3 s it rides a belt along a guide loses 2-3 cm, about half the smallest gap a line's KPIs
count (``min_gap_m`` 0.05 m); less changes no singulation."""
MIN_TOUCHING_RUNS = 3
"""Runs with fish touching a guide the test needs (like every covariate test: fewer cannot be judged)."""


def apply(p: PlantParams, rise: float) -> None:
    p.extensions.guide_wear.rise = rise


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """The slip of fish at a guide against their position along the line (0 at the infeed end, 1 at the outfeed),
    one level per stretch of belt and one for guide contact as nuisance terms; the positions are shuffled among the
    touching rows (under no wear, where along the line a fish touched a guide says nothing of its slip there)."""
    quantity = "slip of fish touching a side guide, beyond the same stretch's fish clear of the guides [m/s]"
    covariate = "position along the line of a fish touching a guide"
    g = rows["guides"]
    touching_runs = g.loc[g["touching"] == 1.0, "run_id"].nunique() if len(g) else 0
    if touching_runs < MIN_TOUCHING_RUNS:
        out = CovariateTest("guide_wear", quantity, covariate, int(len(g)), int(touching_runs))
        out.note = f"fish touched a guide in only {touching_runs} runs"
        return out
    stretch = (g["conveyor_id"] + "/" + g["x_m"].round(3).astype(str)).to_numpy()
    levels = np.unique(stretch)
    nuisance = np.column_stack([(stretch == s).astype(float) for s in levels[1:]] + [g["touching"].to_numpy(float)])
    position = g["x_m"].to_numpy(float)
    span = float(position.max() - position.min()) or 1.0
    shape = (g["touching"].to_numpy(float) * (position - position.min()) / span)[:, None]
    # outliers clipped among the fish touching a guide and among those clear of both apart: fish at a guide slip
    # more, and more variously (pressed by others in a pile), than the many riding alone mid-lane
    slip = g["slip_mps"].to_numpy(float).copy()
    for side in (0.0, 1.0):
        m = g["touching"].to_numpy(float) == side
        slip[m] = robust(slip[m])
    d = Design(slip, g["run_id"].to_numpy(), shape,
               ["x of a fish touching a guide, from the first stretch read (0) to the last (1)"], nuisance,
               within=False, sign=+1, min_effect=MIN_SLIP_MPS, strata=g["touching"].to_numpy(float))
    return covariate_test("guide_wear", quantity, covariate, d, "strata", rng)


def fit(cand: Candidate, ctx: FitContext) -> CandidateFit:
    """On a grid of simulated strengths, on the runs in which fish touched a guide (the others carry no signal)."""
    g = guide_rows(ctx.dataset)
    return fit_on_grid(cand, ctx, set(g.loc[g["touching"] == 1.0, "run_id"]))


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """Fish-guide friction at the outfeed end of the line over that at the infeed end, and both (the model's
    fish-guide friction at the infeed)."""
    rise = values.get("rise", 0.0)
    infeed = ctx.base.friction.fish_guide
    return {"guide_friction_outfeed_over_infeed": float(1.0 + rise), "guide_friction_infeed": float(infeed),
            "guide_friction_outfeed": float(infeed * (1.0 + rise))}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: the slip of fish touching a guide and of fish clear of them along the
    line."""
    g = rows.get("guides")
    if g is not None and len(g):
        for touching, label in ((0.0, "clear of the guides"), (1.0, "touching a guide")):
            part = g[g["touching"] == touching]
            ax.plot(part["x_m"], 100 * part["slip_mps"], "." if touching else ",", alpha=0.5, label=label)
        ax.legend(fontsize=7)
    ax.set(xlabel="position along the line [m]", ylabel="slip riding a belt [cm/s]")


CANDIDATE = Candidate(
    "guide_wear", "fish-guide friction rising along the line: x(1 + rise) at the outfeed end, linear in x",
    ("rise",), "", 0.0, (1.0, 3.0), (-0.8, 10.0), "plant", apply, ("extensions.guide_wear.rise",),
    test=test, decides="more runs with fish pressed against the guides on the downstream belts (bulk drops, a "
                       "narrowing lane)",
    fit=fit, groups=(None,), terms=terms, primary="guide_friction_outfeed_over_infeed", plot=plot,
    explains=(("guides", "touching"), ("guides", "x_m")))
