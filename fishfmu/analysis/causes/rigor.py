"""Rigor: joint stiffness follows hours post mortem (rigor sets in, peaks and resolves).

Signature: the blocked share of photo-eye passages of fish riding alone against the batch's age: a limp fish lies in
the belt and blocks a low beam throughout; a stiff one pivots over the step and the beam flickers (sign -1).
Extension: joints (1 + K exp(-((h - peak) / width)^2)) times stiffer, range lost with it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, bump_shapes, covariate_test
from fishfmu.analysis.extension_fit import fit_levels
from fishfmu.analysis.levels import rigor_limit_loss

MIN_FLICKER = 0.01
"""Rigor is named only if the beams flicker for at least 1 % of a passage more at its peak than without it: a few
ms of a passage's half second to a second, what a photo-eye input scanned every few ms can still tell from a
beam's own jitter (fish of the same batch, limp, vary by a few tenths of a percent from run to run)."""


def apply(p: PlantParams, stiffness_gain: float, peak_h: float | None = None, width_h: float | None = None) -> None:
    p.extensions.rigor_mortis.stiffness_gain = stiffness_gain
    p.extensions.rigor_mortis.limit_loss = rigor_limit_loss(stiffness_gain)
    if peak_h is not None:
        p.extensions.rigor_mortis.peak_h = peak_h
    if width_h is not None:
        p.extensions.rigor_mortis.width_h = width_h


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    """Strength 1: x16 stiffer at the peak; deliberately not the fitted family's range loss."""
    p.extensions.rigor_mortis.stiffness_gain = 15.0 * s
    p.extensions.rigor_mortis.limit_loss = min(0.8, 0.7 * s)


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """Joint stiffness follows hours post mortem; seen in the blocked share of photo-eye passages."""
    ok = rows["passages"].dropna(subset=["hours_post_mortem"])
    shapes, names = bump_shapes(ok["hours_post_mortem"].to_numpy(float))
    d = Design(ok["blocked"].to_numpy(float), ok["run_id"].to_numpy(), shapes, names, np.zeros((len(ok), 0)),
               within=False, sign=-1, min_effect=MIN_FLICKER)
    return covariate_test("rigor_mortis", "blocked share of photo-eye passages of fish alone", "hours post mortem",
                          d, "rows", rng)


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """How many times stiffer the joints are at the peak of rigor than without it (the constant stiffening every run
    has is the base), and when the peak is."""
    k0 = values.get("joint_stiffening", 0.0)
    return {"stiffness_factor_at_peak": float((1.0 + k0 + values.get("stiffness_gain", 0.0)) / (1.0 + k0)),
            "peak_h": float(values.get("peak_h", float("nan")))}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: the blocked share of passages alone against hours post mortem."""
    passages = rows.get("passages")
    if passages is not None and len(passages):
        ax.plot(passages["hours_post_mortem"], passages["blocked"], ".", alpha=0.5)
    ax.set(xscale="log", xlabel="hours post mortem", ylabel="blocked share of a passage")


CANDIDATE = Candidate(
    "rigor_mortis", "extra joint stiffness at full rigor (x soft stiffness; range lost with it), when rigor peaks and "
    "how long it lasts", ("stiffness_gain", "peak_h", "width_h"), "x", 0.0, (), (0.0, 50.0), "plant", apply,
    ("extensions.rigor_mortis.stiffness_gain", "extensions.rigor_mortis.limit_loss", "extensions.rigor_mortis.peak_h",
     "extensions.rigor_mortis.width_h"),
    test=test,
    decides="more runs at ages between 4 and 48 h post mortem with fish riding alone past the photo-eyes",
    fit=fit_levels, groups=("transfers", "transfers", "transfers"), level_model="rigor_mortis", synthetic=hide,
    terms=terms, primary="stiffness_factor_at_peak",
    explains=(("passages", "hours_post_mortem"), ("transfers", "hours_post_mortem")), plot=plot)
