"""KPI statistics over seeds: mean, standard deviation and confidence intervals.

Two intervals, for two different questions:

* :func:`mean_ci` (every KPI): Student-t interval of the mean over seeds,
  ``mean +- t(0.975, n - 1) * sd / sqrt(n)`` with the sample standard deviation (``ddof = 1``).
  Each seed is one batch of fish, one independent sample of the KPI; this is the interval to quote
  for "the singulation rate of this line".
* :func:`wilson_interval` (singulation rate only): Wilson score interval of the *pooled* proportion
  (all singulated fish over all fish of all seeds).  It treats fish as independent trials, which
  they are not (fish of one batch push each other and share their fate), so it can be too narrow
  or too wide for the line; it is given because it stays meaningful with one or two seeds, where
  the t-interval is undefined or huge.

KPIs that a run leaves undefined (``None``: e.g. no gap with a single fish) are left out and
counted in ``n_undefined``.

>>> ci = mean_ci([0.2, 0.4, 0.3])
>>> ci.n, round(ci.mean, 3), round(ci.sd, 3), round(ci.ci_low, 4), round(ci.ci_high, 4)
(3, 0.3, 0.1, 0.0516, 0.5484)
>>> [round(x, 4) for x in wilson_interval(10, 18)]
[0.3372, 0.7544]
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import pandas as pd
from scipy import stats as sps

CONFIDENCE = 0.95


@dataclass(frozen=True)
class MeanCI:
    """The mean of one KPI over seeds with its confidence interval (None where undefined)."""

    n: int
    """seeds with a defined value"""
    n_undefined: int
    """seeds whose run left the KPI undefined (None / NaN)"""
    mean: float | None
    sd: float | None
    """sample standard deviation (ddof = 1); None below two values"""
    ci_low: float | None
    ci_high: float | None


def _defined(values: Iterable[Any]) -> tuple[list[float], int]:
    kept, dropped = [], 0
    for v in values:
        if v is None or (isinstance(v, float) and math.isnan(v)):
            dropped += 1
        else:
            kept.append(float(v))
    return kept, dropped


def mean_ci(values: Iterable[Any], confidence: float = CONFIDENCE) -> MeanCI:
    """Mean, sd and Student-t interval of the mean; one value gives a mean without interval.

    >>> ci = mean_ci([1.0, None, 3.0])       # t(0.975, 1) = 12.706
    >>> ci.n, ci.n_undefined, ci.mean, round(ci.ci_low, 3), round(ci.ci_high, 3)
    (2, 1, 2.0, -10.706, 14.706)
    >>> mean_ci([5.0]).ci_low is None
    True
    """
    x, dropped = _defined(values)
    n = len(x)
    if n == 0:
        return MeanCI(0, dropped, None, None, None, None)
    mean = math.fsum(x) / n
    if n == 1:
        return MeanCI(1, dropped, mean, None, None, None)
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in x) / (n - 1))
    half = float(sps.t.ppf(0.5 + confidence / 2.0, n - 1)) * sd / math.sqrt(n)
    return MeanCI(n, dropped, mean, sd, mean - half, mean + half)


def wilson_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float] | None:
    """Wilson score interval of a proportion; None without trials."""
    if trials <= 0:
        return None
    z = float(sps.norm.ppf(0.5 + confidence / 2.0))
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def summarise(runs: pd.DataFrame, group_cols: Sequence[str], kpis: Sequence[str],
              confidence: float = CONFIDENCE) -> pd.DataFrame:
    """One row per group (sweep point): ``n_runs``, ``n_ok``, ``n_failed``, ``errors`` and, for each
    KPI over the runs that succeeded, ``<kpi>_n``, ``_n_undefined``, ``_mean``, ``_sd``, ``_ci_low``,
    ``_ci_high``; for the singulation rate also the pooled rate and its Wilson interval
    (``singulation_rate_pooled``, ``_wilson_low``, ``_wilson_high``).

    ``runs`` has a ``status`` column ("ok"/"failed"), an ``error`` column and the KPI columns.
    """
    rows = []
    keys = list(group_cols) or None
    groups = runs.groupby(keys, sort=False, dropna=False) if keys else [((), runs)]
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        row: dict[str, Any] = dict(zip(group_cols, key))
        ok = g[g["status"] == "ok"]
        errors = sorted({str(e) for e in g.loc[g["status"] != "ok", "error"] if e is not None and e == e})
        row.update(n_runs=len(g), n_ok=len(ok), n_failed=len(g) - len(ok), errors=" | ".join(errors) or None)
        for k in kpis:
            ci = mean_ci(ok[k] if k in ok else [], confidence)
            row.update({f"{k}_{name}": value for name, value in asdict(ci).items()})
        if {"singulated", "fish_in"} <= set(ok.columns):
            singulated, fish = _defined(ok["singulated"])[0], _defined(ok["fish_in"])[0]
            pooled = (sum(singulated), sum(fish)) if len(singulated) == len(fish) == len(ok) else (0, 0)
            interval = wilson_interval(int(pooled[0]), int(pooled[1]), confidence)
            row["singulation_rate_pooled"] = pooled[0] / pooled[1] if pooled[1] else None
            row["singulation_rate_wilson_low"], row["singulation_rate_wilson_high"] = interval or (None, None)
        rows.append(row)
    return pd.DataFrame(rows)
