"""How fast each belt comes up to speed: the drives' response, calibrated on their logs.

A run's drive log starts with the line starting: each belt's setpoint steps up from rest and the belt
follows as its drive allows, before any fish lies on it.  That start-up is the drive's response alone (no
load), so it is fitted there without any simulation of fish: the built-in conveyor-drive FMU is run on the
logged setpoints of each start-up at a grid of inverter ramps (``ramp_acceleration``, what sets how fast a
belt reaches its speed), and each drive gets the ramp with the least error on the fit runs, a 95 % interval
(bootstrap over the fit runs), a held-out gain (each fit run scored with the ramp chosen on the other folds)
and the error of the held-out runs before and after.  A ramp is applied only if its gain's interval is above
zero.  A drive that does not ramp (one that follows a step as a first-order lag) gets the ramp that comes
closest, and its remaining error says how close that is.

What a drive does under load (droop) is left to ``diagnose``, on the rest of the log: the **drive residuals**
(:func:`drive_residuals`), logged belt speed minus the drive model's away from setpoint changes, against the belt
load.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset, Run

from fishfmu.analysis.fitting import folds, gain_with_ci, vertex
from fishfmu.analysis.resim import simulate_drive
from fishfmu.fmu.archive import open_fmu
from fishfmu.fmu.build import builtin_fmu

RAMP_FACTORS = np.sqrt(2.0) ** np.arange(-7, 8)
"""Ramps tried, as factors of the model's, sqrt(2) apart: 1/11 to 11 times (the built-in drive's 2 m/s^2: 0.18 to
22.6 m/s^2, a belt at 1.5 m/s at speed in 8.5 s to 0.07 s)."""
FINE_POINTS = 8
"""Ramps tried between the best one's neighbours on the coarse grid (an even number: the best one is not tried twice)."""
STARTUP_MAX_S = 3.0
"""Longest stretch of a start-up used (a ramp of 0.5 m/s^2 takes the fastest belt to speed in 3 s)."""
MIN_STEP = 0.2
"""A start-up is a setpoint step the belt has to follow: at least this share of the setpoint away from it."""


@dataclass
class DriveResponseFit:
    conveyor_id: str
    model_mps2: float
    """The drive FMU's ramp as given."""
    value_mps2: float
    """Applied: the fitted ramp when kept, else the model's."""
    fitted_mps2: float = float("nan")
    ci95: tuple[float, float] = (float("nan"), float("nan"))
    heldout_gain: float = float("nan")
    heldout_gain_ci95: tuple[float, float] = (float("nan"), float("nan"))
    kept: bool = False
    rms_mps: dict[str, dict[str, float]] = field(default_factory=dict)
    """``{"fit": {"before": .., "after": ..}, "heldout": {...}}``: RMS of logged minus model belt speed over the
    start-ups, with the model's ramp and with the applied one."""
    startups: int = 0
    """Start-ups it was fitted on (fit runs)."""


def startup(run: Run, conveyor_id: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t, setpoint, logged speed) of the belt's first start-up in the run: from the sample before its setpoint
    first steps away from the belt's speed, until the setpoint changes again, the first fish is dropped or
    :data:`STARTUP_MAX_S` have passed.  None when the log has no such step, or fewer than 20 samples of it (a
    start-up logged that coarsely says little about a response of tenths of a second)."""
    b = run.belts[run.belts["conveyor_id"] == conveyor_id].sort_values("t_s")
    t, sp, v = (b[k].to_numpy(float) for k in ("t_s", "setpoint_mps", "speed_mps"))
    step = np.flatnonzero((np.abs(sp) > 0.05) & (np.abs(sp - v) > MIN_STEP * np.abs(sp)))
    if not len(step):
        return None
    i0 = max(int(step[0]) - 1, 0)
    t_end = t[i0] + STARTUP_MAX_S
    if len(run.fish):
        t_end = min(t_end, float(run.fish["drop_t_s"].min()))
    changes = np.flatnonzero(np.abs(np.diff(sp[i0 + 1:])) > 1e-9)
    if len(changes):
        t_end = min(t_end, t[i0 + 1 + int(changes[0])])
    w = slice(i0, int(np.searchsorted(t, t_end, side="right")))
    if w.stop - w.start < 20:
        return None
    return t[w], sp[w], v[w]


def fit_drive_responses(dataset: Dataset, fit_runs: list[str], rng: np.random.Generator,
                        model_mps2: float | None = None) -> list[DriveResponseFit]:
    """Each drive's ramp from the start-ups of ``fit_runs`` (the others held out); see the module docstring.  The
    model's ramp is the built-in drive's (``model_mps2`` None: its declared start value, 2 m/s^2), not one a
    scenario may set: the gains say what the fitted ramp gains over that."""
    out = []
    with open_fmu(builtin_fmu("conveyor_drive")) as fmu:
        model_mps2 = float(fmu.variables["ramp_acceleration"].start) if model_mps2 is None else model_mps2
        values = model_mps2 * RAMP_FACTORS
        logs = np.log(values)
        for c in dataset.line.conveyors:
            ups = {r.id: s for r in dataset.runs if (s := startup(r, c.id)) is not None}

            def sq(run_id: str, ramp: float) -> float:
                t, sp, v = ups[run_id]
                model = simulate_drive(fmu, f"drive_{c.id}", t, sp, np.zeros_like(t), v[0], {"ramp_acceleration": ramp})
                return float(np.sum((v - model) ** 2))
            fit_ids = [r for r in fit_runs if r in ups]
            held_ids = [r for r in ups if r not in fit_runs]
            fit = DriveResponseFit(c.id, model_mps2, model_mps2, startups=len(fit_ids))
            if len(fit_ids) < 2:
                out.append(fit)
                continue
            coarse = np.array([[sq(r, float(a)) for a in values] for r in fit_ids])  # fit runs x ramps
            # then finely around the best (a parabola through points sqrt(2) apart misplaces the minimum by a few %)
            i = int(np.argmin(coarse.sum(axis=0)))
            fine = np.exp(np.linspace(logs[max(i - 1, 0)], logs[min(i + 1, len(logs) - 1)], FINE_POINTS + 2)[1:-1])
            tried = np.concatenate([values, fine])
            order = np.argsort(tried)
            tried = tried[order]
            table = np.concatenate([coarse, np.array([[sq(r, float(a)) for a in fine] for r in fit_ids])], axis=1)[:, order]
            fit.fitted_mps2 = float(np.exp(vertex(np.log(tried), table.sum(axis=0))))
            boot = [float(np.exp(vertex(np.log(tried), table[rng.integers(0, len(fit_ids), len(fit_ids))].sum(axis=0))))
                    for _ in range(300)]
            fit.ci95 = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
            # held out: each fold scored at the coarse ramp best on the other folds (the fine ramps were placed
            # with every fit run, the held-out one too)
            at_model = len(RAMP_FACTORS) // 2
            u, e0 = np.zeros(len(fit_ids)), coarse[:, at_model].copy()
            for fold in folds(fit_ids):
                test = np.array([r in fold for r in fit_ids])
                best = int(np.argmin(coarse[~test].sum(axis=0)))
                u[test] = e0[test] - coarse[test, best]
            fit.heldout_gain, fit.heldout_gain_ci95 = gain_with_ci(u, e0, rng)
            fit.kept = bool(fit.heldout_gain_ci95[0] > 0.0)
            if fit.kept:
                fit.value_mps2 = float(f"{fit.fitted_mps2:.3g}")

            def rms(ids: list[str], ramp: float) -> float:
                count = sum(len(ups[r][0]) for r in ids)
                return float(np.sqrt(sum(sq(r, ramp) for r in ids) / count)) if count else float("nan")
            fit.rms_mps = {g: {"before": rms(ids, model_mps2), "after": rms(ids, fit.value_mps2)}
                           for g, ids in (("fit", fit_ids), ("heldout", held_ids))}
            out.append(fit)
    return out


def drive_residuals(check: pd.DataFrame, settle_s: float = 0.5, band: float = 0.05) -> pd.DataFrame:
    """Logged belt speed minus the drive model's, away from setpoint changes (ramps are not droop): after each
    change, and after the log's start (a drive starting from rest ramps like after a change), only once both
    the logged and the model speed have come within ``band`` of the setpoint, and ``settle_s`` later."""
    if check.empty:
        return check.assign(residual_mps=[])
    sp = check["setpoint_mps"].to_numpy()
    t = check["t_s"].to_numpy()
    near = ((np.abs(check["measured_mps"].to_numpy() - sp) <= band * np.abs(sp))
            & (np.abs(check["model_mps"].to_numpy() - sp) <= band * np.abs(sp)))
    starts = np.concatenate([[0], np.flatnonzero(np.abs(np.diff(sp)) > 1e-6) + 1, [len(t)]])
    steady = np.zeros(len(t), dtype=bool)
    for a, b in zip(starts[:-1], starts[1:]):  # each stretch of one setpoint
        hit = np.flatnonzero(near[a:b])
        if len(hit):
            steady[a:b] = t[a:b] >= t[a + hit[0]] + settle_s
    steady &= np.abs(sp) > 0.05
    out = check[steady].copy()
    out["residual_mps"] = out["measured_mps"] - out["model_mps"]
    return out


def drive_residuals_averaged(check: pd.DataFrame, window_s: float = 0.5, settle_s: float = 0.5) -> pd.DataFrame:
    """:func:`drive_residuals` averaged over windows of ``window_s`` (residual, load and time).

    A drive log's sample-to-sample noise is no model error, but at 100 Hz it can be most of the
    residual's variance and hide a droop of a few mm/s; droop follows the load, which changes over
    tenths of a second, so averaging keeps it and removes most of the noise.  Windows with fewer
    than half their samples (cut by a setpoint change) are left out."""
    steady = drive_residuals(check, settle_s)
    if steady.empty:
        return steady
    dt = float(np.median(np.diff(check["t_s"].to_numpy()))) if len(check) > 1 else window_s
    need = max(1, int(0.5 * window_s / max(dt, 1e-9)))
    binned = steady.assign(window=np.floor(steady["t_s"].to_numpy() / window_s).astype(int))
    g = binned.groupby("window")
    out = g[["t_s", "residual_mps", "load_force_n", "load_mass_kg", "setpoint_mps", "measured_mps", "model_mps"]].mean()
    return out[g.size() >= need].reset_index(drop=True)
