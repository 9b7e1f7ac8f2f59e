"""Fitting a named cause's extension of the model, the three ways a candidate can be fitted, and its held-out gain.

A candidate (:class:`fishfmu.analysis.candidate.Candidate`) names one of these as its ``fit``:

- :func:`fit_levels`: a run-level effect (mucus, rigor) from the level responses of the calibration
  (:mod:`fishfmu.analysis.levels`), judged against the constant levels on the same rows;
- :func:`fit_on_grid`: the extended plant simulated at a grid of strengths on the runs that carry the signal
  (directional friction, adhesion), extended beyond an end where the error still falls;
- :func:`fit_drive`: the drive logs' residuals, linear in the load (drive droop).

Every one of them reports the same held-out score (:func:`fishfmu.analysis.fitting.heldout_score`).  ``cand`` is
the :class:`~fishfmu.analysis.candidate.Candidate` being fitted (not imported here: it names its fitter).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.calibrate import Calibration
from fishfmu.analysis.fitting import HeldOut, folds, heldout_score, vertex
from fishfmu.analysis.levels import MODELS, PASSAGE, Responses, fit_model
from fishfmu.analysis.residuals import RunResiduals, pair_residuals, residuals_of
from fishfmu.analysis.resim import resimulate_many

MIN_GAIN = 0.02
"""The named cause's fitted model is reported as carrying over to held-out runs when it removes at least this
fraction of their error with its 95 % interval above zero."""
NOT_CONFIRMED = "named by its signature, model extension not confirmed"
"""What a named cause is when its fitted extension does not beat the base on held-out runs: the data show the cause,
the model of it does not pay, and the extension is never handed over as a fix (``fragment.toml`` carries it as
comments only)."""


@dataclass
class CandidateFit:
    name: str
    values: dict[str, float] = field(default_factory=dict)
    """Fitted parameter values (all runs)."""
    ci95: dict[str, tuple[float, float]] = field(default_factory=dict)
    heldout_gain: float = float("nan")
    heldout_gain_ci95: tuple[float, float] = (float("nan"), float("nan"))
    heldout_rms_before: float = float("nan")
    heldout_rms_after: float = float("nan")
    error_unit: str = "m"
    grid: pd.DataFrame | None = None
    """Error per run and grid value (plant candidates)."""
    gain_by_run: dict[str, float] = field(default_factory=dict)
    """Held-out error each run's residuals lose with the candidate (in the squares of ``error_unit``)."""
    base_by_run: dict[str, float] = field(default_factory=dict)
    """Held-out error of each run with the base (calibrated) model, in the same units as ``gain_by_run``."""
    side_by_side: pd.DataFrame | None = None
    """The held-out runs as the candidate's test reads them, one row per run: ``run_id``, ``covariate`` (its value in
    the run), ``measured``, ``base`` and ``extended`` (the run's mean of the quantity; extended: with what was
    chosen on the other runs); its ``attrs`` name the covariate and the quantity.  None where not drawn."""
    at_grid_end: dict[str, str] = field(default_factory=dict)
    """Parameters fitted at an end of the values searched (``lowest`` or ``highest``): the data may want a value
    beyond what was tried, and the report says so rather than give the end as the answer."""
    failed_values: dict[float, str] = field(default_factory=dict)
    """Strengths at which the extended model could not carry every run (a fish lost from the line, a blow-up): how
    many runs failed and the first error.  They are left out of the fit, not scored as the base: the measured runs
    lost nothing there, so the data's strength lies short of them."""

    def score(self, s: HeldOut) -> "CandidateFit":
        """Takes the held-out score (gain, interval, per run, RMS before and after)."""
        self.heldout_gain, self.heldout_gain_ci95, self.gain_by_run = s.gain, s.ci95, s.by_run
        self.base_by_run = s.base_by_run
        self.heldout_rms_before, self.heldout_rms_after = s.rms_before, s.rms_after
        return self

    @property
    def confirmed(self) -> bool:
        """The extension beats the base on held-out runs: a gain of at least ``MIN_GAIN``, its interval above zero."""
        return bool(self.heldout_gain >= MIN_GAIN and self.heldout_gain_ci95[0] > 0.0)

    def carried_by(self) -> tuple[str, float] | None:
        """(run, its share of the gain) when one run carries more than half of a gain of at least ``MIN_GAIN``:
        the bootstrap over runs leaves that run out of a third of its samples, so the interval reaches below zero
        whatever the size of the gain; more runs like it decide (a user should know that, not only "none")."""
        total = sum(self.gain_by_run.values())
        if not self.gain_by_run or self.heldout_gain < MIN_GAIN or total <= 0.0:
            return None
        run, u = max(self.gain_by_run.items(), key=lambda kv: kv[1])
        return (run, u / total) if u > 0.5 * total else None


@dataclass
class FitContext:
    """What a candidate's fitter may use: the dataset, its calibration (the calibrated model, its fit runs, their
    residuals and level responses), the drive residuals, the worker pool and the random stream."""

    dataset: Dataset
    cal: Calibration
    drive: pd.DataFrame
    pool: object
    rng: np.random.Generator
    say: Callable[[str], None]
    extended_sims: dict[str, list] = field(default_factory=dict)
    """Every run re-simulated with a model the calibrated one extended, by that model (its JSON): simulated once."""


def grid_ends(values: dict[str, float], grids: dict[str, np.ndarray]) -> dict[str, str]:
    """The parameters whose fitted value is at the lowest or highest of the values searched (a grid of one value is
    no search)."""
    out = {}
    for name, grid in grids.items():
        g = np.asarray(grid, dtype=float)
        if name not in values or len(g) < 2:
            continue
        if np.isclose(values[name], g.max()):
            out[name] = f"highest value searched ({g.max():.4g})"
        elif np.isclose(values[name], g.min()):
            out[name] = f"lowest value searched ({g.min():.4g})"
    return out


# ------------------------------------------------------------------------------------- run-level effects
def fit_levels(cand, ctx: FitContext) -> CandidateFit:
    """A run-level candidate's fit from its level model, judged on the rows its levels change against the constant
    levels there."""
    on = ctx.cal.responses.only(MODELS[cand.level_model].kinds)
    model = fit_model(MODELS[cand.level_model], on, ctx.rng)
    reference = fit_model(MODELS["constant"], on, ctx.rng)
    fit = CandidateFit(cand.name, values=dict(model.values), ci95=dict(model.ci95),
                       error_unit="x noise (the rows it is judged on: lags, drops or photo-eye passages, each "
                                  "over its noise)",
                       at_grid_end=grid_ends(model.values, dict(zip(MODELS[cand.level_model].parameters,
                                                                    MODELS[cand.level_model].grids(on)))))
    fit.side_by_side = _passages_side_by_side(MODELS[cand.level_model], model, reference, on, ctx.cal)
    return fit.score(heldout_score(on.runs, reference.cv_ss - model.cv_ss, reference.cv_ss,
                                   int(np.count_nonzero(on.row_weight)), ctx.rng))


def _passages_side_by_side(level_model, model, reference, on: Responses, cal: Calibration) -> pd.DataFrame | None:
    """Each run held out, as a beam sees it: the mean blocked share of its passages of fish alone, measured, with
    the base (the constant levels) and with the extended model, each chosen on the other runs.  A beam sees our
    fish's outline with an offset of its own, taken out as the fit takes it out (the model's values are measured
    plus the model's residual less its beam's mean over the runs).  None where no passage rows are judged."""
    rows = (on.row_kind == PASSAGE) & (on.row_weight > 0)
    if not rows.any():
        return None
    measured = {r.run_id: float(r.passages["blocked_measured"][np.isfinite(r.passages["dblocked"])].mean())
                for r in cal.baseline if len(r.passages)}
    ref_model = MODELS["constant"]
    side = []
    for j, run in enumerate(on.runs):
        mine = rows & (on.row_run == j)
        if not mine.any() or run not in measured:
            continue
        error = {}
        for label, lm, fitted in (("base", ref_model, reference), ("extended", level_model, model)):
            values = fitted.cv_values[j]
            error[label] = float(on.residuals(lm.levels(on.hours, *(values[p] for p in lm.parameters)))[mine].mean())
        side.append({"run_id": run, "covariate": float(on.hours[j]), "measured": measured[run],
                     "base": measured[run] + error["base"], "extended": measured[run] + error["extended"]})
    if not side:
        return None
    out = pd.DataFrame(side).sort_values("covariate", kind="stable").reset_index(drop=True)
    out.attrs.update(covariate="hours post mortem",
                     quantity="blocked share of photo-eye passages of fish alone (mean over the run's beams)")
    return out


# ------------------------------------------------------------------------------------- a grid of simulations
def grid_fit(cand, base: dict[str, RunResiduals], grid: dict[float, dict[str, RunResiduals]],
             rng: np.random.Generator) -> CandidateFit:
    """Cross-validated choice of strength on the simulated grid (the ``off`` value is the baseline)."""
    values = np.array([cand.off, *sorted(grid)])
    table = {cand.off: base, **grid}
    groups = cand.groups
    # score on the runs that carry the candidate's signal (adhesion: runs with touching pairs)
    runs = sorted(r for r in base if sum(base[r].squares(g)[1] for g in groups) > 0) or sorted(base)
    ss = {g: np.array([[table[v][r].squares(g)[0] for r in runs] for v in values]) for g in groups}
    nn = {g: np.array([[table[v][r].squares(g)[1] for r in runs] for v in values]) for g in groups}
    u = np.zeros(len(runs))
    e0 = np.zeros(len(runs))
    chosen: dict[str, float] = {}
    for fold in folds(runs):
        test = np.array([r in fold for r in runs])
        for g in groups:
            # the simulated strength nearest the vertex of the other folds' error curve (a held-out run is scored
            # where it was simulated; the bare minimum of a coarse grid would pick an erratic point whole)
            fitted = vertex(values, ss[g][:, ~test].sum(axis=1) / np.maximum(nn[g][:, ~test].sum(axis=1), 1))
            best = int(np.argmin(np.abs(values - fitted)))
            u[test] += ss[g][0, test] - ss[g][best, test]
            e0[test] += ss[g][0, test]
            chosen.update({r: float(values[best]) for r in fold})
    n_total = sum(nn[g][0].sum() for g in groups)
    pair_levels = groups == ("pair_levels",)
    fit = CandidateFit(cand.name, error_unit="share of parting" if pair_levels else "m").score(
        heldout_score(runs, u, e0, n_total, rng))
    if pair_levels:
        fit.side_by_side = _pairs_side_by_side(runs, table, cand.off, chosen)
    # fitted values on all runs, with a bootstrap over runs
    for g, pname in zip(groups, cand.parameters):
        err = ss[g].sum(axis=1) / np.maximum(nn[g].sum(axis=1), 1)
        fit.values[pname] = vertex(values, err)
        boot = []
        for _ in range(300):
            i = rng.integers(0, len(runs), len(runs))
            boot.append(vertex(values, ss[g][:, i].sum(axis=1) / np.maximum(nn[g][:, i].sum(axis=1), 1)))
        fit.ci95[pname] = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    fit.at_grid_end = grid_ends(fit.values, {p: values for p in cand.parameters})
    fit.grid = pd.DataFrame([{"value": v, "run_id": r, "ss": sum(ss[g][i, j] for g in groups),
                              "n": int(sum(nn[g][i, j] for g in groups))}
                             for i, v in enumerate(values) for j, r in enumerate(runs)])
    return fit


def _pairs_side_by_side(runs: list[str], table: dict[float, dict[str, RunResiduals]], off: float,
                        chosen: dict[str, float]) -> pd.DataFrame:
    """Each held-out run's pairs: how far they parted 1.5 s after a transfer as a share of how far their belts
    would part them, measured, with the base model and with the extended one (its strength chosen on the other
    runs), against the number of pairs the run has."""
    side = []
    for r in runs:
        p = table[off][r].pairs
        ok = np.isfinite(p["parting_m"].to_numpy(float))
        if not ok.any():
            continue
        parting, measured = p["parting_m"].to_numpy(float)[ok], p["separation_m"].to_numpy(float)[ok]
        row = {"run_id": r, "covariate": float(ok.sum()), "measured": float(np.mean(measured / parting))}
        for label, v in (("base", off), ("extended", chosen[r])):
            row[label] = row["measured"] + table[v][r].pair_share()[0]
        side.append(row)
    out = pd.DataFrame(side, columns=["run_id", "covariate", "measured", "base", "extended"])
    out.attrs.update(covariate="touching pairs at the transfers in the run",
                     quantity="pairs' separation 1.5 s after a transfer, as a share of how far their belts part them")
    return out


def beyond_the_ends(cand, base: dict[str, RunResiduals], grid: dict[float, dict[str, RunResiduals]],
                    failed: dict[float, dict[str, str]] | None = None) -> list[float]:
    """Values to simulate beyond the grid where a group's error is lowest at its end (within the bounds):
    a fit stuck at the edge of its grid would report the edge, not the strength.  Where a value that far out
    ``failed`` to simulate, the point halfway to it is tried instead."""
    table = {cand.off: base, **grid}
    values = sorted(table)
    failed = failed or {}
    extra = []
    for g in cand.groups:
        err = []
        for v in values:
            sq = [table[v][r].squares(g) for r in base]
            err.append(sum(a for a, _ in sq) / max(sum(n for _, n in sq), 1))
        i = int(np.argmin(err))
        if i == len(values) - 1 and values[-1] < cand.bounds[1]:
            end, out = values[-1], min(values[-1] + 1.5 * (values[-1] - values[-2]), cand.bounds[1])
            wall = min((v for v in failed if v > end), default=None)
        elif i == 0 and values[0] > cand.bounds[0]:
            end, out = values[0], max(values[0] - 1.5 * (values[1] - values[0]), cand.bounds[0])
            wall = max((v for v in failed if v < end), default=None)
        else:
            continue
        if wall is not None and abs(out - end) >= abs(wall - end):
            out = 0.5 * (end + wall)
        extra.append(out)
    return sorted({round(v, 6) for v in extra} - set(values) - set(failed))


def _failures_text(value: float, unit: str, errors: dict[str, str], n_runs: int) -> str:
    run, error = sorted(errors.items())[0]
    return f"{value:g} {unit} failed on {len(errors)} of {n_runs} runs ({run}: {error})"


def fit_on_grid(cand, ctx: FitContext, run_ids: set[str] | None = None) -> CandidateFit:
    """The candidate at its grid of strengths on the runs that carry its signal (``run_ids`` where the candidate
    says which; those with touching pairs for a candidate fitted on pairs; else the calibration's fit runs), extended
    once beyond an end where the error still falls, against the calibrated model.  A strength at which a run fails
    to simulate is left out (:attr:`CandidateFit.failed_values`)."""
    dataset, cal = ctx.dataset, ctx.cal
    cur_by_run = {b.run_id: b for b in cal.after if not b.error}
    if run_ids is not None:
        fit_runs = [r for r in dataset.runs if r.id in run_ids and r.id in cur_by_run]
    elif cand.needs_pairs:
        fit_runs = [r for r in dataset.runs if r.id in cur_by_run and len(pair_residuals(r, r.tracks, dataset.line))]
    else:
        fit_runs = [r for r in dataset.runs if r.id in set(cal.fit_runs) and r.id in cur_by_run]
    if not fit_runs:  # nothing carries its signal: no gain either way
        return CandidateFit(cand.name, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="m")
    sub = dataset.subset(fit_runs)
    base_by_run = {r.id: cur_by_run[r.id] for r in fit_runs}
    grid: dict[float, dict[str, RunResiduals]] = {}
    failed: dict[float, dict[str, str]] = {}
    values, passes = list(cand.grid), 0
    while values:
        ctx.say(f"fit {cand.name}: {', '.join(f'{v:g}' for v in values)} {cand.unit} on {len(fit_runs)} runs")
        sims = resimulate_many(dataset.line, fit_runs * len(values),
                               [cand.params(cal.params, v) for v in values for _ in fit_runs], pool=ctx.pool,
                               workers=1, residuals=True)
        for k, v in enumerate(values):
            res = {r.run_id: r for r in residuals_of(sub, sims[k * len(fit_runs):(k + 1) * len(fit_runs)])
                   if r.run_id in base_by_run}
            if errors := {rid: str(r.error) for rid, r in res.items() if r.error}:
                # the model at this strength loses what the measured runs kept: left out (scored as the base, it
                # bent the error curve's vertex towards it), and the search stays short of it
                failed[v] = errors
                ctx.say(f"fit {cand.name}: {_failures_text(v, cand.unit, errors, len(fit_runs))}")
            else:
                grid[v] = res
        # the grid, then once beyond an end where the error still falls; once more halfway back if that failed
        passes += 1
        if not grid or passes > 2 or (passes == 2 and not set(values) & set(failed)):
            break
        values = beyond_the_ends(cand, base_by_run, grid, failed)
    if not grid:  # no strength simulated on every run: nothing to fit, no gain
        fit = CandidateFit(cand.name, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="m")
    else:
        fit = grid_fit(cand, base_by_run, grid, ctx.rng)
        for p, where in fit.at_grid_end.items():  # an end the failures set, not the search
            end = max(cand.off, *grid) if where.startswith("highest") else min(cand.off, *grid)
            if any((v > end) == where.startswith("highest") for v in failed):
                fit.at_grid_end[p] = f"{where.split()[0]} value that simulated on every run ({end:.4g})"
    fit.failed_values = {v: _failures_text(v, cand.unit, e, len(fit_runs)) for v, e in sorted(failed.items())}
    return fit
