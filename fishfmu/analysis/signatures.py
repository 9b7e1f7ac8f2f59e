"""Whether each candidate cause's quantity follows its covariate beyond chance, and the decision.

A candidate cause is a physical quantity that follows a covariate (``docs/diagnosis.md``): mucus, fish-belt
friction with hours post mortem; rigor, joint stiffness with hours; directional friction, friction with the
fish's slip direction; drive droop, belt speed with the load carried; adhesion, a force between fish in contact;
photo-eye latency, where a fish is at a photo-eye's edges with its speed.
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
from fishfmu.analysis.observations import drive_rows, drop_rows, edge_rows, guide_rows, pair_rows, passage_rows

__all__ = ["ALPHA", "SUGGESTIVE", "CovariateTest", "Judgement", "judge", "significant"]


# ------------------------------------------------------------------------------------------------- the decision

ALPHA = 0.02
"""A candidate is named only if the chance of its signature under no effect (its p-value) is at most this: with
five candidates, at most about one dataset in ten without an effect is named as one (measured on the
benchmark of independent datasets, ``docs/diagnosis.md``; photo-eye latency, the sixth, not yet measured there)."""
SUGGESTIVE = 0.10
"""A p-value above :data:`ALPHA` up to this is reported as undecided (what more runs would decide), not as none."""


@dataclass
class Judgement:
    """The covariate tests of every candidate and the cause they name."""

    tests: list[CovariateTest]
    causes: list[str]
    """The named candidates, strongest first (empty: none named)."""
    undecided: list[str] = field(default_factory=list)
    """Candidates these runs cannot decide (not judged, or suggestive), each with what would decide it."""
    rows: dict[str, pd.DataFrame] = field(default_factory=dict, repr=False)
    """What the tests read: ``drops``, ``passages``, ``drive``, ``pairs``, ``edges``, ``guides`` and
    ``model_pairs`` (for plots)."""

    left_out: list[str] = field(default_factory=list)
    """Candidates switched off (``fishfmu diagnose --without``): not tested, never named."""

    @property
    def cause(self) -> str:
        """The named candidates joined by ``+`` (strongest first), or ``none``."""
        return "+".join(self.causes) if self.causes else "none"

    @property
    def decision(self) -> str:
        if self.causes:
            by_name = {t.candidate: t for t in self.tests}
            return "; ".join(f"{c}: {by_name[c].quantity} follows {by_name[c].covariate} (p = {by_name[c].p_value:.3f}, "
                             f"held-out gain {by_name[c].heldout_gain:.1%})" for c in self.causes)
        return "none" + (f"; cannot decide {', '.join(self.undecided)}" if self.undecided else "")


def significant(t: CovariateTest) -> bool:
    """Named only when unlikely by chance and better than the constant on held-out runs."""
    return bool(t.judged and t.p_value <= ALPHA and t.heldout_gain > 0.0 and t.effect >= t.min_effect)


def judge(dataset: Dataset, rng: np.random.Generator, model: Dataset | None = None,
          without: tuple[str, ...] = ()) -> Judgement:
    """Every candidate's covariate test, and the causes: every significant candidate, the one least likely by chance
    first (ties, at the permutations' resolution: the larger lower end of the held-out gain's interval); none
    significant: none. Each test reads its own quantity, or the same rows along a covariate the others' tests take
    out (directional friction compares fish within a run, mucus runs of different ages), so a term significant
    alone stays significant with the others in the model: several causes at once are each named. ``model``: the
    runs re-simulated with the constant (calibrated) model, in the measured-data format, for adhesion (the other
    tests read the measured data alone). ``without``: candidates switched off."""
    rows = {"drops": drop_rows(dataset), "passages": passage_rows(dataset), "drive": drive_rows(dataset),
            "pairs": pair_rows(dataset), "edges": edge_rows(dataset), "guides": guide_rows(dataset)}
    if model is not None:
        rows["model_pairs"] = pair_rows(model)
    unknown = sorted(set(without) - set(CANDIDATES))
    if unknown:
        raise ValueError(f"no candidate cause named {', '.join(unknown)} (known: {', '.join(CANDIDATES)})")
    tests = [c.test(rows, rng) for c in CANDIDATES.values() if c.name not in without]
    named = sorted((t for t in tests if significant(t)), key=lambda t: (t.p_value, -t.heldout_gain_ci95[0]))
    causes = [t.candidate for t in named]
    undecided = []
    for t in tests:
        if not t.judged:
            undecided.append(f"{t.candidate} ({t.note}; {CANDIDATES[t.candidate].decides} would decide)")
        elif not causes and not significant(t) and t.p_value <= SUGGESTIVE and t.effect >= t.min_effect:
            undecided.append(f"{t.candidate} (p = {t.p_value:.3f}; {CANDIDATES[t.candidate].decides} would decide)")
    return Judgement(tests, causes, undecided, rows, [c for c in CANDIDATES if c in without])
