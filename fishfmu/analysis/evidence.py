"""Cheap evidence first: which candidate causes do the baseline residuals point at?

From one re-simulation of every run with the model as it is (see :mod:`fishfmu.analysis.residuals`), each
candidate of the registry (:mod:`fishfmu.analysis.candidates`) names one of these tests of the residuals:

- :class:`RunLevelShape`: between runs, the runs' mean lags (heading effect removed) against a
  shape in hours post mortem: a mucus index ``1 - exp(-h / 24 h)`` or a rigor index ``exp(-((h - 24 h) / 20 h)^2)``
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
from fishfmu.analysis.evidence_base import SUPPORT_Z, Residuals


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


def evidence_table(rows: pd.DataFrame, pairs: pd.DataFrame, drive: pd.DataFrame, seed: int = 0,
                   candidates: dict[str, Candidate] | None = None) -> pd.DataFrame:
    """Every candidate's evidence (|z|), strongest first, with ``supported`` = |z| of at least ``SUPPORT_Z``
    (shown beside the fits as an explanation; every candidate is fitted whatever its evidence)."""
    table = evidence_rows(Residuals(rows, pairs, drive), np.random.default_rng(seed), candidates)
    table["evidence"] = table["z"].abs()
    table["supported"] = table["evidence"] >= SUPPORT_Z
    return table.sort_values("evidence", ascending=False, kind="stable").reset_index(drop=True)
