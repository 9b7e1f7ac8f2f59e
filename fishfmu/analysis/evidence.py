"""Cheap evidence first: which candidate causes do the baseline residuals point at?

From one re-simulation of every run with the model as it is (see :mod:`fishfmu.analysis.residuals`), each
candidate of the registry (:mod:`fishfmu.analysis.candidates`) names one of these tests of the residuals:

- :class:`HeadingSlope`: the change of along-line error across each belt for fish alone on it
  (``lag_m``) against the fish's heading, within runs (``direction_friction``: head first or tail
  first);
- :class:`RunLevelShape`: between runs, the runs' mean lags (heading effect removed) against a
  shape in hours post mortem: a constant (``belt_friction``: every fish slips too much or too
  little), a mucus index ``1 - exp(-h / 24 h)`` or a rigor index ``exp(-((h - 24 h) / 20 h)^2)``
  (``mucus_friction``, ``rigor_mortis``: one rises and stays, the other comes and goes);
- :class:`PairSeparation`: pairs of fish crossing a transfer together: does the simulation pull
  them apart further than measured (``adhesion``)?
- :class:`DriveSlope`: the drive residual (logged minus model belt speed) against the belt load:
  does the belt slow down under load more than the model (``drive_droop``)?

Each coefficient becomes a z-score (a cluster bootstrap over runs for what varies within runs, a
t-test on run means for what varies between them), so that a dataset of few runs does not look
more certain than it is.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from fishfmu.analysis.candidates import CANDIDATES, Candidate
from fishfmu.analysis.evidence_base import SUPPORT_Z, Residuals, RunLevelShape


def _registry(candidates: dict[str, Candidate] | None) -> dict[str, Candidate]:
    return CANDIDATES if candidates is None else candidates


def evidence_rows(data: Residuals, rng: np.random.Generator, candidates: dict[str, Candidate] | None = None,
                  table: str | None = None) -> pd.DataFrame:
    """Each candidate's evidence (in registry order; ``table``: only the candidates whose test reads that table)."""
    return pd.DataFrame([{"candidate": c.name, **c.evidence(data, rng)} for c in _registry(candidates).values()
                         if table is None or c.evidence.table == table])


def belt_evidence(rows: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """Evidence of the candidates tested on the lags of fish alone on a belt."""
    return evidence_rows(Residuals(rows, pd.DataFrame(), pd.DataFrame()), rng, table="rows")


def run_level_choice(table: pd.DataFrame, candidates: dict[str, Candidate] | None = None) -> list[str]:
    """Among the candidates that act through hours post mortem (and a constant), the one whose shape fits
    the runs' mean lags best (and a second if it fits almost as well): fitting all would cost time and
    they mostly explain the same thing."""
    run_level = [c.name for c in _registry(candidates).values() if isinstance(c.evidence, RunLevelShape)]
    t = table[table["candidate"].isin(run_level) & table["supported"]]
    t = t.dropna(subset=["shape_rss"]).sort_values("shape_rss")
    if t.empty:
        return []
    best = t.iloc[0]
    out = [best["candidate"]]
    if len(t) > 1 and t.iloc[1]["shape_rss"] <= 1.2 * best["shape_rss"]:
        out.append(t.iloc[1]["candidate"])
    return out


def evidence_table(rows: pd.DataFrame, pairs: pd.DataFrame, drive: pd.DataFrame, seed: int = 0,
                   candidates: dict[str, Candidate] | None = None) -> pd.DataFrame:
    """Every candidate's evidence (|z|), strongest first, with ``supported`` = worth fitting."""
    table = evidence_rows(Residuals(rows, pairs, drive), np.random.default_rng(seed), candidates)
    table["evidence"] = table["z"].abs()
    table["supported"] = table["evidence"] >= SUPPORT_Z
    return table.sort_values("evidence", ascending=False, kind="stable").reset_index(drop=True)
