"""Whether each candidate cause's quantity follows its covariate beyond chance, and the decision.

A candidate cause is a physical quantity that follows a covariate (``docs/diagnosis.md``): mucus, fish-belt
friction with hours post mortem; rigor, joint stiffness with hours; directional friction, friction with the
fish's slip direction; drive droop, belt speed with the load carried; adhesion, a force between fish in contact.
Each is judged where physics says the constant model predicts *no* dependence on that covariate, so that no base
model has to be right first and none can absorb the effect: each candidate's module (:mod:`fishfmu.analysis.causes`)
holds its test on the rows read here (:mod:`fishfmu.analysis.observations`), all of them the same covariate test
(:mod:`fishfmu.analysis.covariates`).  The p-value controls the false-positive rate (:data:`ALPHA`); the held-out
gain says the term carries over to runs it was not fitted on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.analysis.covariates import CovariateTest
from fishfmu.analysis.observations import drive_rows, drop_rows, guide_rows, pair_rows, passage_rows

__all__ = ["ALPHA", "SUGGESTIVE", "CovariateTest", "Judgement", "judge", "significant"]


# ------------------------------------------------------------------------------------------------- the decision

ALPHA = 0.02
"""A candidate is named only if the chance of its signature under no effect (its p-value) is at most this: with
five candidates, at most about one dataset in ten without an effect is named as one (measured on the
benchmark of independent datasets, ``docs/diagnosis.md``)."""
SUGGESTIVE = 0.10
"""A p-value above :data:`ALPHA` up to this is reported as undecided (what more runs would decide), not as none."""


@dataclass
class Judgement:
    """The covariate tests of every candidate and the cause they name."""

    tests: list[CovariateTest]
    cause: str
    """The named candidate, or ``none``."""
    undecided: list[str] = field(default_factory=list)
    """Candidates these runs cannot decide (not judged, or suggestive), each with what would decide it."""
    rows: dict[str, pd.DataFrame] = field(default_factory=dict, repr=False)
    """What the tests read: ``drops``, ``passages``, ``drive``, ``pairs``, ``guides`` and ``model_pairs`` (for
    plots)."""

    @property
    def decision(self) -> str:
        if self.cause != "none":
            t = next(t for t in self.tests if t.candidate == self.cause)
            return (f"{self.cause}: {t.quantity} follows {t.covariate} (p = {t.p_value:.3f}, held-out gain "
                    f"{t.heldout_gain:.1%})")
        return "none" + (f"; cannot decide {', '.join(self.undecided)}" if self.undecided else "")


def significant(t: CovariateTest) -> bool:
    """Named only when unlikely by chance and better than the constant on held-out runs."""
    return bool(t.judged and t.p_value <= ALPHA and t.heldout_gain > 0.0 and t.effect >= t.min_effect)


def judge(dataset: Dataset, rng: np.random.Generator, model: Dataset | None = None) -> Judgement:
    """Every candidate's covariate test, and the cause: of the significant candidates the one least likely by
    chance (ties, at the permutations' resolution: the larger lower end of the held-out gain's interval); none
    significant: ``none``. ``model``: the runs re-simulated with the constant (calibrated) model, in the
    measured-data format, for adhesion (the other tests read the measured data alone)."""
    rows = {"drops": drop_rows(dataset), "passages": passage_rows(dataset), "drive": drive_rows(dataset),
            "pairs": pair_rows(dataset), "guides": guide_rows(dataset)}
    if model is not None:
        rows["model_pairs"] = pair_rows(model)
    tests = [c.test(rows, rng) for c in CANDIDATES.values()]
    named = [t for t in tests if significant(t)]
    cause = min(named, key=lambda t: (t.p_value, -t.heldout_gain_ci95[0])).candidate if named else "none"
    undecided = []
    for t in tests:
        if not t.judged:
            undecided.append(f"{t.candidate} ({t.note}; {CANDIDATES[t.candidate].decides} would decide)")
        elif cause == "none" and not significant(t) and t.p_value <= SUGGESTIVE and t.effect >= t.min_effect:
            undecided.append(f"{t.candidate} (p = {t.p_value:.3f}; {CANDIDATES[t.candidate].decides} would decide)")
    return Judgement(tests, cause, undecided, rows)
