"""Directional friction: friction follows the direction the fish slips in relative to itself (head or tail first).

Signature: the slip of fish dropped alone against their heading (+1 head downstream: the fish slides tail first
relative to the belt); with isotropic friction the slip does not depend on which way the fish points.  A fish sliding
against its scales grips more (sign -1).  Extension: head first x(1 - a), tail first x(1 + a), fitted on a grid of
simulated strengths on the calibration's fit runs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test, robust
from fishfmu.analysis.extension_fit import fit_on_grid


def apply(p: PlantParams, asymmetry: float) -> None:
    """Slipping head first (along the scales) x(1 - a), tail first x(1 + a), sideways unchanged."""
    p.extensions.direction_friction.head = 1.0 - asymmetry
    p.extensions.direction_friction.tail = 1.0 + asymmetry


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    p.extensions.direction_friction.head = 1.0 - 0.4 * s
    p.extensions.direction_friction.tail = 1.0 + 0.4 * s


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """A fish dropped head downstream slides tail first relative to the belt, one head upstream head first."""
    ok = rows["drops"].dropna(subset=["heading"])
    d = Design(robust(ok["slip_s"].to_numpy(float)), ok["run_id"].to_numpy(),
               ok[["heading"]].to_numpy(float), ["cos(heading at the drop)"], np.zeros((len(ok), 0)), within=True,
               sign=-1)
    return covariate_test("directional_friction", "slip of fish dropped alone [s]",
                          "heading relative to the belt's motion", d, "within", rng)


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """Friction slipping head first over friction slipping tail first."""
    a = values.get("asymmetry", 0.0)
    return {"head_tail_friction_ratio": float((1.0 - a) / (1.0 + a))}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: the slip of drops alone against the fish's heading."""
    drops = rows.get("drops")
    if drops is not None and len(drops):
        ax.plot(drops["heading"], 1e3 * drops["slip_s"], ".", alpha=0.5)
    ax.set(xlabel="cos(heading) at the drop\n(+1 head downstream)", ylabel="slip of a drop alone [ms]")


CANDIDATE = Candidate(
    "directional_friction", "fish-belt friction by slip direction: head first x(1 - a), tail first x(1 + a)",
    # a >= 0: the physics fixes the sign (against the scales grips more; the test is one-sided, sign -1): a fit
    # searching below 0 found head-first grip fixing the base model's take-up at the transfers, not scales
    ("asymmetry",), "", 0.0, (0.25, 0.5), (0.0, 0.75), "plant", apply,
    ("extensions.direction_friction.head", "extensions.direction_friction.tail"),
    test=test, decides="more fish dropped alone onto the infeed, both head downstream and head upstream",
    fit=fit_on_grid, groups=("transfers",), synthetic=hide, terms=terms,
    primary="head_tail_friction_ratio",
    explains=(("drops", "heading"), ("transfers", "heading")), plot=plot)
