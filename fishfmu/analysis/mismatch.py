"""What the calibrated base model gets wrong the same way everywhere, and how well it fits: said once, as what it is.

The scan (:mod:`fishfmu.analysis.scan`) judges every dependence beyond these; ``diagnose`` reports them beside its
answer, never as a cause or as an unexplained discrepancy:

- each transfer's mean lag of fish alone (model minus measured), the same for every fish, run and age;
- the **take-up law**: how the lag grows with the speed step at a transfer, one law at every transfer.  On the
  independent simulator's data our fish are taken up faster at every transfer, the more so the larger the step; a
  fish slides about ``dv^2 / (2 mu g)`` before it rides, so the law is a term in the step and one in its square.
  Judged as one law across transfers, a transfer whose lag grows with the step beyond it is still found there (a
  slippery landing zone), while the model's own law is not called a discrepancy at the transfer with the largest
  step (issue 41's false alarm on data without an effect);
- how far the lags scatter beyond these against what the tracker's own noise makes of a lag.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.covariates import robust
from fishfmu.analysis.fitting import heldout_score
from fishfmu.analysis.scan import TAKE_UP


def tracker_noise_m(dataset: Dataset) -> float:
    """The tracker's own noise along the line [m], from the measured tracks alone: the second differences of a fish's
    position at evenly spaced samples (a steadily moving fish's are noise, sqrt(6) sigma), robust to the
    accelerations at drops and transfers (median absolute deviation)."""
    d2 = []
    for run in dataset.runs:
        for _, tr in run.tracks.groupby("fish_id", sort=False):
            t, x = tr["t_s"].to_numpy(float), tr["x_m"].to_numpy(float)
            if len(t) < 5:
                continue
            dt = np.diff(t)
            even = np.abs(dt[1:] - dt[:-1]) <= 0.1 * dt[:-1]
            d2.append((x[2:] - 2 * x[1:-1] + x[:-2])[even])
    if not d2:
        return float("nan")
    a = np.concatenate(d2)
    return float(1.4826 * np.median(np.abs(a - np.median(a))) / np.sqrt(6.0))


def base_mismatch(tables: dict[str, pd.DataFrame], rng: np.random.Generator, n_boot: int = 1000) -> dict:
    """What the calibrated model gets wrong the same way for every fish: each transfer's mean lag (model minus
    measured, fish alone) with a 95 % interval from resampling runs."""
    t = tables.get("transfers")
    out: dict[str, dict] = {}
    if t is None or not len(t):
        return out
    for loc, rows in t.groupby("conveyor_id", sort=True):
        per_run = rows.groupby("run_id")["lag_m"].agg(["sum", "count"])
        s, n = per_run["sum"].to_numpy(float), per_run["count"].to_numpy(float)
        idx = rng.integers(0, len(s), size=(n_boot, len(s)))
        boot = s[idx].sum(axis=1) / np.maximum(n[idx].sum(axis=1), 1)
        out[str(loc)] = {"mean_lag_m": float(s.sum() / n.sum()), "ci95_m": [float(np.percentile(boot, 2.5)),
                                                                            float(np.percentile(boot, 97.5))],
                         "fish": int(n.sum()), "runs": int(len(s))}
    return out


def fit_quality(tables: dict[str, pd.DataFrame], noise_m: float) -> dict:
    """How well the model fits the lags of fish alone across transfers, beyond each transfer's constant: their RMS
    against what the tracker's noise alone makes of a lag (a difference of two medians of ``n_samples`` samples
    each: 1.25 sigma / sqrt(n) apiece)."""
    t = tables.get("transfers")
    if t is None or not len(t) or not np.isfinite(noise_m):
        return {}
    centred = t["lag_m"] - t.groupby("conveyor_id")["lag_m"].transform("mean")
    n = t["n_samples"].clip(lower=1).to_numpy(float) if "n_samples" in t.columns else np.full(len(t), 10.0)
    expected = float(np.sqrt(np.mean(2.0 * (1.2533 * noise_m) ** 2 / n)))
    rms = float(np.sqrt(np.mean(centred.to_numpy(float) ** 2)))
    return {"lag_rms_m": rms, "tracker_noise_m": noise_m, "noise_lag_rms_m": expected,
            "ratio": rms / expected if expected > 0 else float("nan"), "fish_transfers": int(len(t))}


def take_up_law(tables: dict[str, pd.DataFrame], rng: np.random.Generator, n_boot: int = 1000) -> dict:
    """The base model's take-up law at the transfers: the lags of fish alone fitted with a level per transfer, a term
    in the heading and ``a step + b step^2`` shared by every transfer (the scan's nuisance, :data:`TAKE_UP`).  Its
    held-out gain over the levels and heading alone (each run left out in turn, interval from resampling runs), and
    at each transfer what it makes over the data's steps: the lag at its largest step less the lag at its smallest,
    with an interval from resampling runs.  Empty without belt logs or with one speed step a transfer."""
    t = tables.get("transfers")
    cols = ["lag_m", "heading", "conveyor_id", "run_id", *TAKE_UP]
    if t is None or not len(t) or any(c not in t.columns for c in cols):
        return {}
    t = t.dropna(subset=cols)
    runs = t["run_id"].astype(str).to_numpy()
    if len(np.unique(runs)) < 3 or all(np.ptp(g.to_numpy(float)) <= 0 for _, g in t.groupby("conveyor_id")[TAKE_UP[0]]):
        return {}
    loc = t["conveyor_id"].astype(str).to_numpy()
    places = np.unique(loc)
    y = t["lag_m"].to_numpy(float).copy()
    for v in places:
        y[loc == v] = robust(y[loc == v])
    levels = np.column_stack([(loc == v).astype(float) for v in places] + [t["heading"].to_numpy(float)])
    law = t[list(TAKE_UP)].to_numpy(float)
    full = np.column_stack([levels, law])

    def fit(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.linalg.lstsq(x[rows], y[rows], rcond=None)[0]

    groups = np.unique(runs)
    e0, e1 = np.zeros(len(groups)), np.zeros(len(groups))
    for i, g in enumerate(groups):
        train, held = runs != g, runs == g
        e0[i] = float(np.sum((y[held] - levels[held] @ fit(levels, train)) ** 2))
        e1[i] = float(np.sum((y[held] - full[held] @ fit(full, train)) ** 2))
    score = heldout_score(list(groups), e0 - e1, e0, len(y), rng)
    a, b = fit(full, np.ones(len(y), dtype=bool))[-2:]
    index = {g: np.flatnonzero(runs == g) for g in groups}
    boot = []
    for _ in range(n_boot):
        rows = np.concatenate([index[g] for g in rng.choice(groups, len(groups))])
        boot.append(fit(full, rows)[-2:])
    boot = np.array(boot)
    out = {}
    for v in places:
        step = t.loc[loc == v, TAKE_UP[0]].to_numpy(float)
        lo, hi = float(step.min()), float(step.max())
        made = boot[:, 0] * (hi - lo) + boot[:, 1] * (hi ** 2 - lo ** 2)
        out[str(v)] = {"step_mps": [lo, hi], "lag_range_m": float(a * (hi - lo) + b * (hi ** 2 - lo ** 2)),
                       "ci95_m": [float(np.percentile(made, 2.5)), float(np.percentile(made, 97.5))]}
    return {"a_m_per_mps": float(a), "b_s2_per_m": float(b), "heldout_gain": score.gain,
            "heldout_gain_ci95": list(score.ci95), "transfers": out}


def take_up_text(law: dict) -> str:
    """One sentence for the decision: the law when its held-out gain is above zero (interval), else nothing."""
    if not law or law["heldout_gain_ci95"][0] <= 0.0:
        return ""
    per = ", ".join(f"{v['lag_range_m'] * 100:+.1f} cm at {c} (steps {v['step_mps'][0]:.2f}-{v['step_mps'][1]:.2f} m/s)"
                    for c, v in law["transfers"].items())
    lo, hi = law["heldout_gain_ci95"]
    return ("The base model's take-up at the transfers (one law at every transfer, not a cause): its lag of fish alone "
            f"(model minus measured) changes with the speed step by {per}; held-out gain {law['heldout_gain']:.1%} "
            f"[{lo:.1%}, {hi:.1%}]. " + ("Our fish are taken up faster than measured, the more so the larger the step."
                                         if sum(v["lag_range_m"] for v in law["transfers"].values()) > 0 else
                                         "Our fish are taken up slower than measured, the more so the larger the step."))
