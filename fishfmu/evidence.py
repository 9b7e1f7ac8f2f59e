"""Cheap evidence first: which candidate causes do the baseline residuals point at?

From one re-simulation of every run with the model as it is (see :mod:`fishfmu.residuals`):

- the change of along-line error across each belt for fish alone on it (``lag_m``) against the
  conditions each candidate depends on: the fish's heading (``direction_friction``: head first or
  tail first, within runs), and between runs a constant (``belt_friction``: every fish slips too
  much or too little), a mucus index ``1 - exp(-h / 24 h)`` and a rigor index
  ``exp(-((h - 24 h) / 20 h)^2)`` of hours post mortem (``mucus_friction``, ``rigor_mortis``: one
  rises and stays, the other comes and goes);
- pairs of fish crossing a transfer together: does the simulation pull them apart further than
  measured (``adhesion``)?
- the drive residual (logged minus model belt speed) against the belt load: does the belt slow
  down under load more than the model (``drive_droop``)?

Each coefficient becomes a z-score (a cluster bootstrap over runs for what varies within runs, a
t-test on run means for what varies between them), so that a dataset of few runs does not look
more certain than it is.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from fishfmu.residuals import alone

BOOTSTRAP = 400
SUPPORT_Z = 2.0
"""Evidence needed before a candidate is worth fitting by simulation (the held-out gain decides)."""


def mucus_index(hours: np.ndarray) -> np.ndarray:
    return 1.0 - np.exp(-np.asarray(hours, dtype=float) / 24.0)


def rigor_index(hours: np.ndarray) -> np.ndarray:
    return np.exp(-(((np.asarray(hours, dtype=float) - 24.0) / 20.0) ** 2))


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


def belt_evidence(rows: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """Evidence from the lags of fish alone on a belt.

    Heading varies between fish of a run: its slope is estimated within runs (each run's mean taken
    out) and its uncertainty by a bootstrap over runs.  Hours post mortem (and a constant offset)
    vary only between runs, so those are tested on the runs' mean lags (heading effect removed),
    one candidate at a time, with Student's t on (runs - 2) degrees of freedom, turned into the
    equivalent z.  A condition that does not vary gives no evidence.
    """
    free = alone(rows).dropna(subset=["lag_m", "heading", "hours_post_mortem"])
    names = ["belt_friction", "direction_friction", "mucus_friction", "rigor_mortis"]
    result = {n: {"candidate": n, "coefficient": np.nan, "sd": np.nan, "z": 0.0, "n": len(free), "shape_rss": np.nan}
              for n in names}
    if len(free) < 6:
        return pd.DataFrame(result.values())
    run = free["run_id"].to_numpy()
    y = free["lag_m"].to_numpy(float)
    h = free["heading"].to_numpy(float)
    yc = y - free.groupby("run_id")["lag_m"].transform("mean").to_numpy()
    hc = h - free.groupby("run_id")["heading"].transform("mean").to_numpy()

    def slope(idx: np.ndarray):
        d = float(np.sum(hc[idx] ** 2))
        return float(np.sum(hc[idx] * yc[idx]) / d) if d > 1e-9 else None

    b_h = slope(np.arange(len(y))) if np.sum(hc**2) > 1e-9 else 0.0
    if b_h is not None and np.std(hc) > 0.05:
        boot = _cluster_bootstrap(run, slope, rng)
        resid = yc - b_h * hc
        se = float(np.sqrt(np.sum(resid**2) / max(len(y) - 1, 1) / np.sum(hc**2)))
        sd = max(float(boot.std(ddof=1)) if len(boot) > 2 else 0.0, se)
        result["direction_friction"].update(coefficient=b_h, sd=sd, z=b_h / sd if sd > 0 else 0.0)
    # run level: mean lag per run with the heading effect removed, against each candidate's shape in
    # hours post mortem.  Mucus and rigor vanish for a fresh fish, a friction error does not: each is a
    # one-parameter model through the origin of its own index (a constant for belt friction)
    adj = free.assign(adj=y - (b_h or 0.0) * h).groupby("run_id").agg(m=("adj", "mean"),
                                                                       hours=("hours_post_mortem", "mean"))
    m, hours, n_runs = adj["m"].to_numpy(), adj["hours"].to_numpy(), len(adj)
    shapes = {"belt_friction": np.ones(n_runs), "mucus_friction": mucus_index(hours),
              "rigor_mortis": rigor_index(hours)}
    for name, x in shapes.items():
        if n_runs < 2 or (name != "belt_friction" and np.std(x) < 0.05):
            continue
        b = float(np.dot(x, m) / np.dot(x, x))
        resid = m - b * x
        se = float(np.sqrt(np.sum(resid**2) / (n_runs - 1) / np.dot(x, x)))
        t = b / se if se > 0 else (np.inf if b else 0.0)
        result[name].update(coefficient=b, sd=se, z=_z_from_t(t, n_runs - 1), shape_rss=float(np.sum(resid**2)))
    return pd.DataFrame(result.values())


def run_level_choice(table: pd.DataFrame) -> list[str]:
    """Among the candidates that act through hours post mortem (and a constant), the one whose shape fits
    the runs' mean lags best (and a second if it fits almost as well): fitting all would cost time and
    they mostly explain the same thing."""
    t = table[table["candidate"].isin(["belt_friction", "mucus_friction", "rigor_mortis"]) & table["supported"]]
    t = t.dropna(subset=["shape_rss"]).sort_values("shape_rss")
    if t.empty:
        return []
    best = t.iloc[0]
    out = [best["candidate"]]
    if len(t) > 1 and t.iloc[1]["shape_rss"] <= 1.2 * best["shape_rss"]:
        out.append(t.iloc[1]["candidate"])
    return out


def pair_evidence(pairs: pd.DataFrame, rng: np.random.Generator) -> dict:
    """Adhesion: mean extra separation of close pairs in the simulation (positive: simulated fish part sooner)."""
    p = pairs.dropna(subset=["dsep_m"])
    if len(p) < 3 or p["run_id"].nunique() < 2:
        return {"candidate": "adhesion", "coefficient": np.nan, "sd": np.nan, "z": 0.0, "n": len(p)}
    d = p["dsep_m"].to_numpy(float)
    boot = _cluster_bootstrap(p["run_id"].to_numpy(), lambda idx: float(d[idx].mean()), rng)
    sd = max(float(boot.std(ddof=1)), float(d.std(ddof=1)) / np.sqrt(len(d)))
    mean = float(d.mean())
    return {"candidate": "adhesion", "coefficient": mean, "sd": sd, "z": max(0.0, mean / sd) if sd > 0 else 0.0,
            "n": len(p)}


def drive_evidence(drive: pd.DataFrame, rng: np.random.Generator) -> dict:
    """Drive droop: slope of (logged - model) belt speed against load; negative means the belt droops more."""
    d = drive.dropna(subset=["residual_mps", "load_force_n"])
    if len(d) < 20 or d["run_id"].nunique() < 2 or np.std(d["load_force_n"]) < 1.0:
        return {"candidate": "drive_droop", "coefficient": np.nan, "sd": np.nan, "z": 0.0, "n": len(d)}
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
    return {"candidate": "drive_droop", "coefficient": float(s), "sd": sd, "z": z, "n": len(d)}


def evidence_table(rows: pd.DataFrame, pairs: pd.DataFrame, drive: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """Every candidate's evidence (|z|), strongest first, with ``supported`` = worth fitting."""
    rng = np.random.default_rng(seed)
    table = pd.concat([belt_evidence(rows, rng), pd.DataFrame([pair_evidence(pairs, rng), drive_evidence(drive, rng)])],
                      ignore_index=True)
    table["evidence"] = table["z"].abs()
    table["supported"] = table["evidence"] >= SUPPORT_Z
    return table.sort_values("evidence", ascending=False, kind="stable").reset_index(drop=True)
