"""Mucus: fish-belt friction follows hours post mortem as the slaughter mucus dries.

Signature: the slip of fish dropped alone onto the infeed (the time they lose to the belt beyond their fall) against
the batch's age; with one friction coefficient a fish wholly on one belt slides ``v / (2 mu g)`` whatever its age.
Drying raises friction, so the slip falls (sign -1).  Extension: friction x(1 + gain (1 - exp(-h / tau))).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test, log_hours_shapes, robust
from fishfmu.analysis.extension_fit import fit_levels


def apply(p: PlantParams, gain: float, time_constant_h: float | None = None) -> None:
    p.extensions.mucus_friction.gain = gain
    if time_constant_h is not None:
        p.extensions.mucus_friction.time_constant_h = time_constant_h


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    """Strength 1: the mucus dries and friction doubles from fresh to dry."""
    p.extensions.mucus_friction.gain = 1.0 * s


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """Fish-belt friction follows hours post mortem; seen in the slip of drops alone (the belt's speed a nuisance
    term)."""
    ok = rows["drops"].dropna(subset=["hours_post_mortem"])
    shapes, names = log_hours_shapes(ok["hours_post_mortem"].to_numpy(float))
    d = Design(robust(ok["slip_s"].to_numpy(float)), ok["run_id"].to_numpy(), shapes, names,
               ok[["belt_speed_mps"]].to_numpy(float), within=False, sign=-1)
    return covariate_test("mucus_friction", "slip of fish dropped alone [s]", "hours post mortem", d, "rows", rng)


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """Fish-belt friction at 1 h and at 48 h post mortem (the model's fish-belt friction x the fitted level x the
    drying factor), and how much it rises between them (x)."""
    level = values.get("friction_level", 1.0) * ctx.base.friction.fish_belt
    gain, tau = values.get("gain", 0.0), values.get("time_constant_h", 24.0)
    at = {h: level * (1.0 + gain * (1.0 - np.exp(-h / tau))) for h in (1.0, 48.0)}
    return {"friction_1h": float(at[1.0]), "friction_48h": float(at[48.0]), "rise_1h_to_48h": float(at[48.0] / at[1.0])}


CANDIDATE = Candidate(
    "mucus_friction", "relative change of belt friction once the mucus has dried, and how fast it dries",
    ("gain", "time_constant_h"), "", 0.0, (), (0.0, 8.0), "plant", apply,
    ("extensions.mucus_friction.gain", "extensions.mucus_friction.time_constant_h"),
    test=test,
    decides="more runs of fish dropped one at a time onto the infeed, at more ages post mortem (fresh batches, under "
            "8 h, most of all)",
    fit=fit_levels, groups=("transfers", "transfers"), level_model="mucus_friction", synthetic=hide, terms=terms,
    primary="rise_1h_to_48h")
