"""Singulation KPIs (contracts/kpis.md): one definition for measured and simulated runs.

With N fish dropped and T from the first drop to the moment the last fish clears the outfeed
beam: ``fpm_in = 60 N / T``, ``singulation_rate = singulated / N``, ``fpm_out = 60 singulated / T``.
A fish is *singulated* when its passage of the outfeed beam overlaps no other and the gap to
the fish before and after it is at least ``min_gap_m``.  A gap is the clear time between the end
of the previous passages (the latest end so far) and a passage's start, times the outfeed belt's
speed at the middle of that time; it is negative when passages overlap.  The first fish has no
gap before it, the last none after.  A gap must also be positive: touching fish are not apart,
even with ``min_gap_m = 0``.  Comparisons allow 1 nm for floating-point rounding.

Passages come from :func:`plant.contract.passages.passages` (re-exported here with
:func:`~plant.contract.passages.arrival_times`); :func:`kpis_from_passages` takes any table of passages,
so the arithmetic can be checked by hand:

>>> p = pd.DataFrame({"t_start_s": [10.0, 12.0, 12.5], "t_end_s": [10.5, 12.75, 13.0]})
>>> k = kpis_from_passages(p, n_fish=4, first_drop_t_s=1.0, belt_speed_fn=lambda t: np.full(len(t), 2.0),
...                        min_gap_m=0.05)
>>> k["singulated"], k["doubles_out"], k["lost"], k["throughput_time_s"], k["gap_min_m"], k["fpm_in"]
(1, 2, 1, 12.0, -0.5, 20.0)
>>> kpis_from_passages(p, 5, 1.0, lambda t: np.full(len(t), 2.0), 0.05, rejected=1)["lost"]  # one a device took off
1
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from plant.contract.line import KpiSettings, Line
from plant.contract.passages import (MAX_TRACK_GAP_S, RunTables, SpeedFn, arrival_times, belt_speed_fn, passages,
                                     track_passages)

__all__ = ["KPIS", "KPI_KEYS", "Kpi", "SHOWN_KPI_KEYS", "arrival_times", "compute_kpis", "kpi_keys",
           "kpis_from_passages", "paper_rounded", "passages", "round_half_up", "singulation_table"]

TOL_M = 1e-9
"""Floating-point tolerance on gap comparisons (1 nm)."""


@dataclass(frozen=True)
class Kpi:
    """One KPI of a run: its key in :func:`kpis_from_passages`' result (and in kpis.json, the
    ``[expect]`` table, a sweep's columns), its unit and what it means."""

    key: str
    unit: str
    description: str


KPIS: tuple[Kpi, ...] = (
    Kpi("fish_in", "fish", "fish dropped onto the line (N)"),
    Kpi("throughput_time_s", "s", "from the first drop until the last fish clears the outfeed beam (T)"),
    Kpi("fpm_in", "fish/min", "fish in per minute: 60 N / T"),
    Kpi("singulated", "fish", "fish whose outfeed passage overlaps no other, with at least min_gap_m before and after"),
    Kpi("singulation_rate", "1", "singulated / N"),
    Kpi("fpm_out", "fish/min", "singulated fish per minute: 60 singulated / T"),
    Kpi("lost", "fish", "fish that never passed the outfeed beam"),
    Kpi("doubles_out", "fish", "fish that passed the outfeed beam not singulated: what reaches the machine downstream "
        "as doubles (N = singulated + doubles_out + rejected + lost)"),
    Kpi("rejected", "fish", "fish a device (reject gate, pusher, diverter) took off the line (per device: rejected_by)"),
    Kpi("good_rejected", "fish", "rejected fish that were singulated where they entered their device: their passage of "
        "its x_m overlapped no other and kept min_gap_m (undefined where the devices' log does not name the fish)"),
    Kpi("gap_min_m", "m", "smallest gap between consecutive fish at the outfeed (negative: overlap)"),
    Kpi("gap_median_m", "m", "median gap between consecutive fish at the outfeed"),
    Kpi("gap_p10_m", "m", "10th percentile of the gaps between consecutive fish at the outfeed"),
)
"""Every numeric KPI, the one list of them (fishfmu's scenario, CLI, sweeps and statistics import it)."""

KPI_KEYS: tuple[str, ...] = tuple(k.key for k in KPIS)
"""The KPI keys in the order :func:`kpis_from_passages` returns them; also the column order of a
sweep's ``runs.csv``."""

SHOWN_KPI_KEYS: tuple[str, ...] = (*(k for k in KPI_KEYS if not k.startswith("gap_")),
                                   *sorted((k for k in KPI_KEYS if k.startswith("gap_")),
                                           key=("gap_min_m", "gap_p10_m", "gap_median_m").index))
"""The order of a KPI table for a person: the gap statistics by increasing quantile (min, p10, median)."""


def kpi_keys(*keys: str) -> tuple[str, ...]:
    """A selection of KPI keys in the order given, each checked to be a KPI (a typo fails at import).

    >>> kpi_keys("fpm_out", "lost")
    ('fpm_out', 'lost')
    """
    unknown = [k for k in keys if k not in KPI_KEYS]
    if unknown:
        raise KeyError(f"not KPIs: {', '.join(unknown)}")
    return keys


def _json(x: Any) -> float | None:
    """A plain float, or None where undefined (NaN, inf, None)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def singulation_table(passages: pd.DataFrame, belt_speed_fn: SpeedFn, min_gap_m: float) -> pd.DataFrame:
    """The passages sorted by start, with ``gap_before_m``, ``gap_after_m`` (NaN at the ends) and ``singulated``."""
    p = passages.sort_values("t_start_s", kind="stable").reset_index(drop=True)
    s, e = p["t_start_s"].to_numpy(float), p["t_end_s"].to_numpy(float)
    gaps = np.full(len(p) + 1, np.nan)
    if len(p) > 1:
        last_end = np.maximum.accumulate(e)[:-1]
        clear_s = s[1:] - last_end
        gaps[1:-1] = clear_s * np.asarray(belt_speed_fn(0.5 * (s[1:] + last_end)), dtype=float)
    ok = np.isnan(gaps) | ((gaps > TOL_M) & (gaps >= min_gap_m - TOL_M))
    return p.assign(gap_before_m=gaps[:-1], gap_after_m=gaps[1:], singulated=ok[:-1] & ok[1:])


def kpis_from_passages(passages: pd.DataFrame, n_fish: int, first_drop_t_s: float, belt_speed_fn: SpeedFn,
                       min_gap_m: float, rejected: int = 0, good_rejected: int | None = 0) -> dict[str, Any]:
    """The KPIs of contracts/kpis.md from a table of outfeed passages (``t_start_s``, ``t_end_s``,
    optionally ``source``; one row per fish that passed) and the count of fish devices took off the line (``rejected``,
    of which ``good_rejected`` were singulated there).  Undefined values are None.

    ``method``: "tracks" (no fish count estimated from the beam), "photoeyes" (every passage
    estimated from photo-eye intervals), "mixed", or "none" (no fish passed).
    """
    table = singulation_table(passages, belt_speed_fn, min_gap_m)
    n_out = len(table)
    singulated = int(table["singulated"].sum())
    throughput = float(table["t_end_s"].max() - first_drop_t_s) if n_out else math.nan
    if not throughput > 0:
        throughput = math.nan
    gaps = table["gap_before_m"].to_numpy(float)[1:]
    sources = table["source"] if "source" in table else pd.Series(["tracks"] * n_out, dtype=object)
    n_estimated = int((sources == "photoeye").sum())
    method = ("none" if n_out == 0 else "tracks" if n_estimated == 0 else
              "photoeyes" if n_estimated == n_out else "mixed")
    return {
        "fish_in": int(n_fish),
        "throughput_time_s": _json(throughput),
        "fpm_in": _json(60.0 * n_fish / throughput),
        "singulated": singulated,
        "singulation_rate": _json(singulated / n_fish) if n_fish else None,
        "fpm_out": _json(60.0 * singulated / throughput),
        "lost": max(int(n_fish) - n_out - int(rejected), 0),
        "doubles_out": n_out - singulated,
        "rejected": int(rejected),
        "good_rejected": good_rejected,
        "gap_min_m": _json(gaps.min()) if len(gaps) else None,
        "gap_median_m": _json(np.median(gaps)) if len(gaps) else None,
        "gap_p10_m": _json(np.percentile(gaps, 10)) if len(gaps) else None,
        "method": method,
        "estimated_fish": n_estimated,
        "passage_sources": {str(k): int(v) for k, v in sources.value_counts().sort_index().items()},
        "min_gap_m": float(min_gap_m),
    }


def compute_kpis(run: RunTables, line: Line, kpi: KpiSettings, max_gap_s: float = MAX_TRACK_GAP_S) -> dict[str, Any]:
    """Every KPI of one run (measured or simulated), JSON-serialisable, plus per-fish arrival
    times at every photo-eye as ``arrival_t_s[sensor_id][fish_id]`` (None where not determined)."""
    beam = line.photoeye(kpi.outfeed_photoeye)
    speed = belt_speed_fn(run, line.conveyor_at(beam.x_m).id)
    p = passages(run, line, kpi, max_gap_s)
    rejections = getattr(run, "rejections", None)
    rejections = rejections if rejections is not None else pd.DataFrame({"device_id": [], "fish_id": []})
    out = kpis_from_passages(p, len(run.fish), float(run.fish["drop_t_s"].min()), speed, kpi.min_gap_m,
                             len(rejections), good_rejected(run, rejections, line, kpi.min_gap_m, max_gap_s))
    out["rejected_by"] = {d.id: int((rejections["device_id"] == d.id).sum()) for d in line.devices}
    arr = arrival_times(run, line, max_gap_s)
    out["arrival_t_s"] = {sid: {str(f): _json(t) for f, t in zip(g["fish_id"], g["t_s"])}
                          for sid, g in arr.groupby("sensor_id", sort=False)}
    return out


def good_rejected(run: RunTables, rejections: pd.DataFrame, line: Line, min_gap_m: float,
                  max_gap_s: float = MAX_TRACK_GAP_S) -> int | None:
    """Rejected fish that were singulated where they entered their device: among the passages from tracks of the
    device's ``x_m`` (as of a beam there, at the speed of the belt that brings fish to it), theirs overlapped no other
    and kept ``min_gap_m``.  None when a rejection does not name its fish (a measured log may not)."""
    if rejections.empty:
        return 0
    if rejections["fish_id"].isna().any():
        return None
    good = 0
    for device_id, rows in rejections.groupby("device_id", sort=False):
        device = next(d for d in line.devices if d.id == device_id)
        speed = belt_speed_fn(run, line.conveyor_at(device.x_m - 1e-6).id)  # a gate's: the belt before its gap
        table = singulation_table(track_passages(run, device.x_m, speed, max_gap_s), speed, min_gap_m)
        singulated = set(table["fish_id"][table["singulated"]])
        good += int(rows["fish_id"].isin(singulated).sum())
    return good


def round_half_up(x: float, ndigits: int = 0) -> float:
    """Round as people (and the paper's Table IV) do: halves away from zero.

    >>> round_half_up(172.5), round(172.5)
    (173.0, 172)
    """
    f = 10.0 ** ndigits
    return math.copysign(math.floor(abs(x) * f + 0.5) / f, x)


def paper_rounded(kpis: dict[str, Any]) -> dict[str, float | None]:
    """The six rows of the paper's Table IV, rounded as it did (whole seconds, FPM and percent)."""
    def r(x: float | None, scale: float = 1.0) -> float | None:
        return None if x is None else round_half_up(scale * x)
    return {"fish_in": kpis["fish_in"], "throughput_time_s": r(kpis["throughput_time_s"]),
            "fpm_in": r(kpis["fpm_in"]), "singulated": kpis["singulated"],
            "singulation_rate_pct": r(kpis["singulation_rate"], 100.0), "fpm_out": r(kpis["fpm_out"])}
