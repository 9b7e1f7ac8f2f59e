"""What fitting a model to a measured dataset needs, whatever is fitted (a base parameter by
``fishfmu calibrate``, a candidate cause by ``fishfmu diagnose``): the residuals of a run against its
re-simulation, the error they make up, folds of runs for held-out scores, a bootstrap interval of a
gain, and the minimum of an error curve over a grid of simulated values."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from plant.measured import Dataset

from fishfmu.analysis.residuals import (PAIR_RESIDUAL_DTYPES, alone, belt_residuals, pair_residuals, track_errors,
                                        typed_frame)
from fishfmu.analysis.resim import Resim

HEADING_SPLIT = 0.3
"""|cos(yaw)| above which a fish rides clearly head first or tail first."""


@dataclass
class RunResiduals:
    """One run's residuals against a re-simulation (:mod:`fishfmu.analysis.residuals`)."""

    run_id: str
    rows: pd.DataFrame
    pairs: pd.DataFrame
    track_rms_m: float
    error: str | None = None

    def squares(self, group: str | None = None) -> tuple[float, int]:
        """(sum of squares, count) of this run's residuals: lags of fish alone, extra pair separation.

        ``group``: ``head_first`` / ``tail_first`` rows only (no pairs), for direction friction;
        ``alone``: every fish alone, no pairs; ``transfers``: fish alone after a transfer (not on the first
        belt, where the lag is that of the drop), no pairs; ``pairs``: the pairs only, for adhesion."""
        if group == "pairs":
            d = self.pairs["dsep_m"].to_numpy(float) if len(self.pairs) else np.zeros(0)
            return float(np.sum(d**2)), len(d)
        free = alone(self.rows)
        if group == "head_first":
            free = free[free["heading"] > HEADING_SPLIT]
        elif group == "tail_first":
            free = free[free["heading"] < -HEADING_SPLIT]
        elif group == "transfers":
            free = free[free["belt"] > 0]
        ss = float(np.sum(free["lag_m"].to_numpy(float) ** 2))
        n = len(free)
        if group is None and len(self.pairs):
            d = self.pairs["dsep_m"].to_numpy(float)
            ss, n = ss + float(np.sum(d**2)), n + len(d)
        return ss, n


def residuals_of(dataset: Dataset, resims: list[Resim]) -> list[RunResiduals]:
    """Residuals of each run against its re-simulation (a failed re-simulation has none, and says why)."""
    out = []
    for run, r in zip(dataset.runs, resims):
        if r.residuals is not None:  # computed by the worker that re-simulated the run
            out.append(r.residuals)
            continue
        if r.error:
            empty = track_errors(run.tracks.iloc[0:0], run.tracks.iloc[0:0])
            out.append(RunResiduals(run.id, belt_residuals(run, empty, dataset.line),
                                    typed_frame([], PAIR_RESIDUAL_DTYPES), np.nan, r.error))
            continue
        errors = track_errors(run.tracks, r.sim.tracks)
        rms = float(np.sqrt(np.mean(errors["ex_m"] ** 2))) if len(errors) else np.nan
        out.append(RunResiduals(run.id, belt_residuals(run, errors, dataset.line),
                                pair_residuals(run, r.sim.tracks, dataset.line), rms))
    return out


def folds(run_ids: list[str], k: int = 5) -> list[list[str]]:
    ids = sorted(run_ids)
    k = max(2, min(k, len(ids)))
    return [ids[i::k] for i in range(k)]


def gain_with_ci(u: np.ndarray, e0: np.ndarray, rng: np.random.Generator, n: int = 1000) -> tuple[float, tuple]:
    """Fraction of error removed, sum(u) / sum(e0), with a bootstrap over runs."""
    gain = float(u.sum() / e0.sum()) if e0.sum() > 0 else 0.0
    if len(u) < 2:
        return gain, (float("nan"), float("nan"))
    boot = []
    for _ in range(n):
        i = rng.integers(0, len(u), len(u))
        if e0[i].sum() > 0:
            boot.append(u[i].sum() / e0[i].sum())
    return gain, (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))


def vertex(x: np.ndarray, y: np.ndarray) -> float:
    """Minimum of a parabola through the lowest point and its neighbours (within the grid's range)."""
    order = np.argsort(x)
    x, y = x[order], y[order]
    i = int(np.argmin(y))
    lo, hi = max(0, i - 1), min(len(x), i + 2)
    if hi - lo < 3:
        return float(x[i])
    a, b, _ = np.polyfit(x[lo:hi], y[lo:hi], 2)
    if a <= 0:
        return float(x[i])
    return float(np.clip(-b / (2 * a), x[lo], x[hi - 1]))


