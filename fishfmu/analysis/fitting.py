"""What fitting a model to a measured dataset needs, whatever is fitted (a base parameter by
``fishfmu calibrate``, a candidate cause by ``fishfmu diagnose``): folds of runs for held-out scores, a
bootstrap interval of a gain, and the minimum of an error curve over a grid of simulated values (the
residuals they are computed on: :class:`fishfmu.analysis.residuals.RunResiduals`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    if not boot:  # no error anywhere to remove (a drive logging its setpoint exactly): no interval either
        return gain, (float("nan"), float("nan"))
    return gain, (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))


def vertex(x: np.ndarray, y: np.ndarray) -> float:
    """Minimum of a parabola through the lowest point and its neighbours (within the grid's range)."""
    order = np.argsort(x)
    x, y = x[order], y[order]
    i = int(np.argmin(y))
    lo, hi = max(0, i - 1), min(len(x), i + 2)
    if hi - lo < 3:
        return float(x[i])
    a, b, _ = np.polyfit(x[lo:hi] - x[i], y[lo:hi], 2)  # centred: points close together stay well conditioned
    if a <= 0:
        return float(x[i])
    return float(np.clip(x[i] - b / (2 * a), x[lo], x[hi - 1]))




@dataclass
class HeldOut:
    """The one held-out score every fit reports (a candidate's covariate test, its extension, a calibrated
    constant): per run, the error of the reference (``e0``) and how much of it the model removes (``u``), each run
    scored with what was chosen on the others; the gain is sum(u) / sum(e0) with a bootstrap over runs."""

    gain: float
    ci95: tuple[float, float]
    by_run: dict[str, float]
    base_by_run: dict[str, float]
    """Per run, the reference's held-out error (``e0``): with ``by_run``, the reference and the model side by side."""
    rms_before: float
    rms_after: float


def heldout_score(run_ids: list[str], u: np.ndarray, e0: np.ndarray, n_rows: int, rng: np.random.Generator,
                  n_boot: int = 1000) -> HeldOut:
    """The held-out gain of ``u`` over ``e0`` (one entry per run of ``run_ids``) with its bootstrap interval, and
    the RMS before and after over ``n_rows`` rows."""
    u, e0 = np.asarray(u, dtype=float), np.asarray(e0, dtype=float)
    gain, ci = gain_with_ci(u, e0, rng, n_boot)
    n = max(int(n_rows), 1)
    return HeldOut(gain, ci, {str(r): float(v) for r, v in zip(run_ids, u)},
                   {str(r): float(v) for r, v in zip(run_ids, e0)}, float(np.sqrt(e0.sum() / n)),
                   float(np.sqrt(max(e0.sum() - u.sum(), 0.0) / n)))
