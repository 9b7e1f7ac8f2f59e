"""The tests of the baseline residuals that the candidates name (:class:`HeadingSlope`,
:class:`RunLevelShape`, :class:`PairSeparation`, :class:`DriveSlope`), and the residual tables they
read (:class:`Residuals`).  See :mod:`fishfmu.analysis.evidence` for what each test asks.

Apart from :mod:`fishfmu.analysis.evidence` (which re-exports all of it and runs the registry's tests) because
the registry (:mod:`fishfmu.analysis.candidates`) is built from these classes and :mod:`fishfmu.analysis.evidence`
needs the registry: with the classes here, neither imports the other back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np
import pandas as pd

from fishfmu.analysis.residuals import alone

BOOTSTRAP = 400
SUPPORT_Z = 2.0
"""Evidence needed before a candidate is worth fitting by simulation (the held-out gain decides)."""
MIN_BELT_ROWS = 6
"""Fewer lags of fish alone on a belt than this give no evidence from the belts."""


def _cluster_bootstrap(runs: np.ndarray, stat, rng: np.random.Generator, n: int = BOOTSTRAP) -> np.ndarray:
    """stat(mask of rows) over resamples of whole runs (with replacement)."""
    ids = np.unique(runs)
    by_run = {r: np.flatnonzero(runs == r) for r in ids}
    out = []
    for _ in range(n):
        pick = rng.choice(ids, size=len(ids), replace=True)
        idx = np.concatenate([by_run[r] for r in pick])
        value = stat(idx)
        if value is not None:
            out.append(value)
    return np.array(out)


def _z_from_t(t: float, df: int) -> float:
    """The normal z with the same two-sided p-value as Student's t with df degrees of freedom."""
    from scipy import stats
    if not np.isfinite(t) or df < 1:
        return 0.0
    p = 2.0 * stats.t.sf(abs(t), df)
    return float(np.sign(t) * stats.norm.isf(max(p, 1e-300) / 2.0))


@dataclass
class Residuals:
    """The baseline residual tables the tests read, with what several tests share computed once."""

    rows: pd.DataFrame
    """Per fish and belt (:data:`~fishfmu.analysis.residuals.BELT_RESIDUAL_DTYPES`)."""
    pairs: pd.DataFrame
    """Per close pair at a transfer (:data:`~fishfmu.analysis.residuals.PAIR_RESIDUAL_DTYPES`)."""
    drive: pd.DataFrame
    """Per drive, averaged (:data:`~fishfmu.analysis.residuals.DRIVE_RESIDUAL_DTYPES`)."""

    @cached_property
    def free(self) -> pd.DataFrame:
        """Lags of fish alone on a belt, with a heading and an age."""
        return alone(self.rows).dropna(subset=["lag_m", "heading", "hours_post_mortem"])

    @cached_property
    def centred(self) -> tuple[np.ndarray, np.ndarray]:
        """(lag, heading) of the free rows with each run's mean taken out."""
        free = self.free
        yc = free["lag_m"].to_numpy(float) - free.groupby("run_id")["lag_m"].transform("mean").to_numpy()
        hc = free["heading"].to_numpy(float) - free.groupby("run_id")["heading"].transform("mean").to_numpy()
        return yc, hc

    def heading_slope_of(self, idx: np.ndarray) -> float | None:
        """Within-run slope of lag against heading on these free rows (None: no heading variation)."""
        yc, hc = self.centred
        d = float(np.sum(hc[idx] ** 2))
        return float(np.sum(hc[idx] * yc[idx]) / d) if d > 1e-9 else None

    @cached_property
    def heading_slope(self) -> float:
        """The within-run slope on all free rows (0 without heading variation)."""
        _, hc = self.centred
        return self.heading_slope_of(np.arange(len(hc))) if np.sum(hc**2) > 1e-9 else 0.0

    @cached_property
    def run_means(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean lag with the heading effect removed, hours post mortem) per run."""
        free = self.free
        y, h = free["lag_m"].to_numpy(float), free["heading"].to_numpy(float)
        adj = free.assign(adj=y - (self.heading_slope or 0.0) * h).groupby("run_id").agg(
            m=("adj", "mean"), hours=("hours_post_mortem", "mean"))
        return adj["m"].to_numpy(), adj["hours"].to_numpy()


def _none(n: int, **extra) -> dict:
    return {"coefficient": np.nan, "sd": np.nan, "z": 0.0, "n": n, "shape_rss": np.nan, **extra}


@dataclass(frozen=True)
class HeadingSlope:
    """Lag against heading within runs: its slope, uncertainty from a bootstrap over runs.

    Heading varies between fish of a run, so the slope is estimated within runs (each run's mean
    taken out).  Positive: fish riding head first lag more in the simulation than measured."""

    table: ClassVar[str] = "rows"

    def __call__(self, data: Residuals, rng: np.random.Generator) -> dict:
        free = data.free
        out = _none(len(free))
        if len(free) < MIN_BELT_ROWS:
            return out
        yc, hc = data.centred
        b_h = data.heading_slope
        if b_h is not None and np.std(hc) > 0.05:
            boot = _cluster_bootstrap(free["run_id"].to_numpy(), data.heading_slope_of, rng)
            resid = yc - b_h * hc
            se = float(np.sqrt(np.sum(resid**2) / max(len(yc) - 1, 1) / np.sum(hc**2)))
            sd = max(float(boot.std(ddof=1)) if len(boot) > 2 else 0.0, se)
            out.update(coefficient=b_h, sd=sd, z=b_h / sd if sd > 0 else 0.0)
        return out


@dataclass(frozen=True)
class RunLevelShape:
    """The runs' mean lags (heading effect removed) against a shape in hours post mortem.

    Hours post mortem (and a constant offset) vary only between runs, so this is a one-parameter
    model through the origin of the shape, tested with Student's t on (runs - 1) degrees of freedom
    and turned into the equivalent z.  A shape that does not vary over the runs gives no evidence
    (unless it is a constant: ``varies=False``).  ``shape_rss`` says how well the shape fits."""

    shape: Callable[[np.ndarray], np.ndarray]
    varies: bool = True
    label: str = ""
    """Name in plots ("" : a constant, not plotted)."""
    table: ClassVar[str] = "rows"

    def __call__(self, data: Residuals, rng: np.random.Generator) -> dict:
        out = _none(len(data.free))
        if len(data.free) < MIN_BELT_ROWS:
            return out
        m, hours = data.run_means
        n_runs = len(m)
        x = self.shape(hours)
        if n_runs < 2 or (self.varies and np.std(x) < 0.05):
            return out
        b = float(np.dot(x, m) / np.dot(x, x))
        resid = m - b * x
        se = float(np.sqrt(np.sum(resid**2) / (n_runs - 1) / np.dot(x, x)))
        t = b / se if se > 0 else (np.inf if b else 0.0)
        out.update(coefficient=b, sd=se, z=_z_from_t(t, n_runs - 1), shape_rss=float(np.sum(resid**2)))
        return out


def constant(hours: np.ndarray) -> np.ndarray:
    """The shape of an effect that does not depend on hours post mortem."""
    return np.ones(len(hours))


@dataclass(frozen=True)
class PairSeparation:
    """Mean extra separation of close pairs in the simulation (positive: simulated fish part sooner)."""

    table: ClassVar[str] = "pairs"

    def __call__(self, data: Residuals, rng: np.random.Generator) -> dict:
        p = data.pairs.dropna(subset=["dsep_m"])
        if len(p) < 3 or p["run_id"].nunique() < 2:
            return _none(len(p))
        d = p["dsep_m"].to_numpy(float)
        boot = _cluster_bootstrap(p["run_id"].to_numpy(), lambda idx: float(d[idx].mean()), rng)
        sd = max(float(boot.std(ddof=1)), float(d.std(ddof=1)) / np.sqrt(len(d)))
        mean = float(d.mean())
        return _none(len(p), coefficient=mean, sd=sd, z=max(0.0, mean / sd) if sd > 0 else 0.0)


@dataclass(frozen=True)
class DriveSlope:
    """Slope of (logged - model) belt speed against load; negative means the belt droops more (z > 0)."""

    table: ClassVar[str] = "drive"

    def __call__(self, data: Residuals, rng: np.random.Generator) -> dict:
        d = data.drive.dropna(subset=["residual_mps", "load_force_n"])
        if len(d) < 20 or d["run_id"].nunique() < 2 or np.std(d["load_force_n"]) < 1.0:
            return _none(len(d))
        f, r = d["load_force_n"].to_numpy(float), d["residual_mps"].to_numpy(float)

        def slope(idx: np.ndarray):
            if np.std(f[idx]) < 1e-9:
                return None
            return float(np.polyfit(f[idx], r[idx], 1)[0])

        s, a = np.polyfit(f, r, 1)
        boot = _cluster_bootstrap(d["run_id"].to_numpy(), slope, rng)
        se = float(np.sqrt(np.sum((r - a - s * f) ** 2) / (len(r) - 2) / np.sum((f - f.mean()) ** 2)))
        sd = max(float(boot.std(ddof=1)) if len(boot) > 2 else 0.0, se)
        z = max(0.0, -s / sd) if sd and sd > 0 else 0.0
        return _none(len(d), coefficient=float(s), sd=sd, z=z)
