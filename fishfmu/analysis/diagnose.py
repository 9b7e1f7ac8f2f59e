"""``fishfmu diagnose``: name the cause of what the simulation gets wrong, fit it, measure the gain.

The pipeline is built so that it fits in minutes on a 2-core machine:

0. **Calibration** (unless switched off): the base parameters every line has are fitted first
   (:mod:`fishfmu.analysis.calibrate`), and everything below judges the candidates against the
   calibrated model: a real line's own mismatch with the default model can outweigh any effect.
1. **Baseline.** Every run re-simulated once with the model as it is (calibrated; in parallel processes);
   residuals per fish and belt, per pair of fish at transfers, per drive (:mod:`fishfmu.analysis.residuals`).
   A run whose baseline re-simulation fails stops the diagnosis (:class:`~plant.errors.SimulationError`
   naming the run); a failed simulation during a fit counts as no better than the baseline.
2. **Evidence.** Which candidates' conditions the residuals depend on (each candidate of the
   registry :data:`fishfmu.analysis.candidates.CANDIDATES` names its test in :mod:`fishfmu.analysis.evidence`).
   Only candidates with enough evidence are fitted: those with a test of their own (direction
   friction, adhesion), and of the candidates acting through hours post mortem (or a constant) the
   best-shaped one; at most ``max_fit`` plant candidates.  Drive candidates (drive droop) are
   fitted analytically, so they cost nothing.  With none, the answer is ``none``.
3. **Fit.** Each chosen plant candidate is simulated at a few strengths (its grid, extended once
   beyond an end where the error is still falling) on every run;
   the error of a run is the mean square of its residuals (lag of fish alone on a belt, extra
   separation of close pairs).  Direction-dependent friction has two parameters but they act on
   different fish (tail-first fish slip head first at a transfer, and the other way round), so one
   grid fits both.
4. **Held-out gain.** Runs are split into folds; a strength is chosen on the other folds and scored
   on the held-out one.  The gain is the fraction of held-out error removed; its 95 % interval comes
   from a bootstrap over runs.  A candidate is named the cause only if its gain is at least
   ``MIN_GAIN`` and the interval excludes zero; otherwise the answer is ``none``.
5. **Confirmation.** The named extension with its fitted strength (interpolated between grid
   values) is simulated once more on every run, for the KPIs and errors after.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.errors import SimulationError
from plant.measured import Dataset, Run
from plant.params import PlantParams

from fishfmu.analysis.calibrate import Calibration, calibrate_with_pool
from fishfmu.analysis.candidates import CANDIDATES, Candidate, fragment
from fishfmu.analysis.evidence import evidence_table, run_level_choice
from fishfmu.analysis.evidence_base import RunLevelShape
from fishfmu.analysis.fitting import RunResiduals, folds, gain_with_ci, residuals_of, vertex
from fishfmu.analysis.residuals import (BELT_RESIDUAL_DTYPES, DRIVE_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES,
                               concat_typed, drive_residuals_averaged)
from fishfmu.analysis.resim import Resim, drive_check, pool_for, resimulate_many

MIN_GAIN = 0.02
"""A cause must remove at least this fraction of the held-out error (and its 95 % interval must be above
zero): measurement noise that no model removes can be most of the error, as with noisy drive logs."""


def drive_table(dataset: Dataset, resims: list[Resim], parameters: dict[str, float] | None = None) -> pd.DataFrame:
    """Drive residuals of every run and conveyor, with the drive FMUs' ``parameters`` (None: as they are)."""
    frames = []
    for run, r in zip(dataset.runs, resims):
        if r.error:
            continue
        for c in dataset.line.conveyors:
            check = drive_check(run, r.loads, c.id, parameters or None)
            frames.append(drive_residuals_averaged(check).assign(run_id=run.id, conveyor_id=c.id))
    return concat_typed(frames, DRIVE_RESIDUAL_DTYPES)


@dataclass
class CandidateFit:
    name: str
    evidence_z: float
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

    @property
    def significant(self) -> bool:
        return bool(self.heldout_gain >= MIN_GAIN and self.heldout_gain_ci95[0] > 0.0)


def fit_plant_candidate(name: str, z: float, base: dict[str, RunResiduals], grid: dict[float, dict[str, RunResiduals]],
                        rng: np.random.Generator) -> CandidateFit:
    """Cross-validated choice of strength on the simulated grid (the ``off`` value is the baseline)."""
    cand = CANDIDATES[name]
    values = np.array([cand.off, *sorted(grid)])
    table = {cand.off: base, **grid}
    groups = cand.groups
    # score on the runs that carry the candidate's signal (adhesion: runs with touching pairs)
    runs = sorted(r for r in base if sum(base[r].squares(g)[1] for g in groups) > 0) or sorted(base)
    ss = {g: np.array([[table[v][r].squares(g)[0] for r in runs] for v in values]) for g in groups}
    nn = {g: np.array([[table[v][r].squares(g)[1] for r in runs] for v in values]) for g in groups}
    u = np.zeros(len(runs))
    e0 = np.zeros(len(runs))
    for fold in folds(runs):
        test = np.array([r in fold for r in runs])
        for g in groups:
            best = int(np.argmin(ss[g][:, ~test].sum(axis=1) / np.maximum(nn[g][:, ~test].sum(axis=1), 1)))
            u[test] += ss[g][0, test] - ss[g][best, test]
            e0[test] += ss[g][0, test]
    gain, ci = gain_with_ci(u, e0, rng)
    n_total = sum(nn[g][0].sum() for g in groups)
    fit = CandidateFit(name, z, heldout_gain=gain, heldout_gain_ci95=ci,
                       heldout_rms_before=float(np.sqrt(e0.sum() / max(n_total, 1))),
                       heldout_rms_after=float(np.sqrt(max(e0.sum() - u.sum(), 0.0) / max(n_total, 1))))
    # fitted values on all runs, with a bootstrap over runs
    for g, pname in zip(groups, cand.parameters):
        err = ss[g].sum(axis=1) / np.maximum(nn[g].sum(axis=1), 1)
        fit.values[pname] = vertex(values, err)
        boot = []
        for _ in range(300):
            i = rng.integers(0, len(runs), len(runs))
            boot.append(vertex(values, ss[g][:, i].sum(axis=1) / np.maximum(nn[g][:, i].sum(axis=1), 1)))
        fit.ci95[pname] = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    fit.grid = pd.DataFrame([{"value": v, "run_id": r, "ss": sum(ss[g][i, j] for g in groups),
                              "n": int(sum(nn[g][i, j] for g in groups))}
                             for i, v in enumerate(values) for j, r in enumerate(runs)])
    return fit


def beyond_the_ends(name: str, base: dict[str, RunResiduals], grid: dict[float, dict[str, RunResiduals]]) -> list[float]:
    """Values to simulate beyond the grid where a group's error is lowest at its end (within the bounds):
    a fit stuck at the edge of its grid would report the edge, not the strength."""
    cand = CANDIDATES[name]
    table = {cand.off: base, **grid}
    values = sorted(table)
    extra = []
    for g in cand.groups:
        err = []
        for v in values:
            sq = [table[v][r].squares(g) for r in base]
            err.append(sum(a for a, _ in sq) / max(sum(n for _, n in sq), 1))
        i = int(np.argmin(err))
        if i == len(values) - 1 and values[-1] < cand.bounds[1]:
            extra.append(min(values[-1] + 1.5 * (values[-1] - values[-2]), cand.bounds[1]))
        elif i == 0 and values[0] > cand.bounds[0]:
            extra.append(max(values[0] - 1.5 * (values[1] - values[0]), cand.bounds[0]))
    return sorted({round(v, 6) for v in extra} - set(values))


def fit_drive_candidate(cand: Candidate, z: float, drive: pd.DataFrame, rng: np.random.Generator) -> CandidateFit:
    """A drive candidate's one parameter (drive droop: belt_slip) from the drive residuals: the speed lost per
    newton of load, a linear effect, so no simulation is needed."""
    fit = CandidateFit(cand.name, z, error_unit="m/s")
    (pname,) = cand.parameters
    lo, hi = cand.bounds
    d = drive.dropna(subset=["residual_mps", "load_force_n"])
    runs = sorted(d["run_id"].unique())
    if len(runs) < 2:
        return fit

    def slip(rows: pd.DataFrame) -> float:
        if len(rows) < 3 or np.std(rows["load_force_n"]) < 1e-9:
            return 0.0
        return float(np.clip(-np.polyfit(rows["load_force_n"], rows["residual_mps"], 1)[0], lo, hi))

    u, e0 = np.zeros(len(runs)), np.zeros(len(runs))
    for fold in folds(runs):
        s = slip(d[~d["run_id"].isin(fold)])
        for j, r in enumerate(runs):
            if r in fold:
                rr = d[d["run_id"] == r]
                e0[j] = float(np.sum(rr["residual_mps"] ** 2))
                u[j] = e0[j] - float(np.sum((rr["residual_mps"] + s * rr["load_force_n"]) ** 2))
    fit.heldout_gain, fit.heldout_gain_ci95 = gain_with_ci(u, e0, rng)
    fit.heldout_rms_before = float(np.sqrt(e0.sum() / len(d)))
    fit.heldout_rms_after = float(np.sqrt(max(e0.sum() - u.sum(), 0.0) / len(d)))
    fit.values[pname] = slip(d)
    boot = [slip(pd.concat([d[d["run_id"] == runs[i]] for i in rng.integers(0, len(runs), len(runs))]))
            for _ in range(200)]
    fit.ci95[pname] = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    return fit


@dataclass
class Diagnosis:
    cause: str
    evidence: pd.DataFrame
    fits: list[CandidateFit]
    fragment: str
    base_rms_m: dict[str, float]
    after_rms_m: dict[str, float]
    kpis_before: list[dict]
    kpis_after: list[dict]
    timing_s: dict[str, float]
    baseline: list[RunResiduals]
    drive: pd.DataFrame
    calibration: Calibration | None = None
    """The base model's calibration that came first (None: the model was taken as given)."""

    def ranking(self) -> list[str]:
        fitted = sorted(self.fits, key=lambda f: -np.nan_to_num(f.heldout_gain, nan=-1.0))
        rest = [c for c in self.evidence["candidate"] if c not in {f.name for f in fitted}]
        return [f.name for f in fitted] + rest


def diagnose(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, max_fit: int = 3,
             seed: int = 0, progress: Callable[[str], None] | None = None, calibrate: bool = True) -> Diagnosis:
    """Name the cause of the discrepancy between the model and the dataset (see the module docstring).
    ``calibrate``: first fit the base model to the dataset (:mod:`fishfmu.analysis.calibrate`) and judge
    the candidates against it; off when the base is known to be right (data made by this simulator)."""
    with pool_for(workers) as pool:  # kept for every re-simulation below: a new process pays for importing Exudyn
        return _diagnose(dataset, base or PlantParams(), pool, max_fit, seed, progress or (lambda text: None),
                         calibrate)


def _diagnose(dataset: Dataset, base: PlantParams, pool, max_fit: int, seed: int,
              say: Callable[[str], None], calibrate: bool = True) -> Diagnosis:
    from plant.kpis import compute_kpis
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    runs = dataset.runs
    calibration = None
    if calibrate:  # the calibrated model's re-simulation of every run is the baseline
        calibration = calibrate_with_pool(dataset, base, pool, seed, say)
        base, base_sims = calibration.params, calibration.sims_after
        timing["calibration"] = time.perf_counter() - t0
    else:
        say(f"baseline: re-simulating {len(runs)} runs")
        base_sims = resimulate_many(dataset.line, runs, [base] * len(runs), pool=pool, workers=1)
    failed = [(r.run_id, r.error) for r in base_sims if r.error]
    if failed:  # no baseline for a run, no diagnosis of the dataset: say so now rather than after the fits
        (run_id, error), more = failed[0], failed[1:]
        also = f"; also failed: {', '.join(repr(r) for r, _ in more)}" if more else ""
        raise SimulationError(f"run '{run_id}': {error} (re-simulating it with the model as it is, the baseline of "
                              f"the diagnosis{also})")
    baseline = residuals_of(dataset, base_sims)
    drive = drive_table(dataset, base_sims)
    timing["baseline"] = time.perf_counter() - t0

    rows = concat_typed([b.rows for b in baseline], BELT_RESIDUAL_DTYPES)
    pairs = concat_typed([b.pairs for b in baseline], PAIR_RESIDUAL_DTYPES)
    evidence = evidence_table(rows, pairs, drive, seed)
    say("evidence: " + ", ".join(f"{c} z={z:.1f}" for c, z in zip(evidence["candidate"], evidence["evidence"])))

    fits: list[CandidateFit] = []
    base_by_run = {b.run_id: b for b in baseline if not b.error}
    supported = set(evidence.loc[evidence["supported"], "candidate"])
    # candidates tested on their own are fitted when supported; those acting through hours post mortem compete
    plant_choice = [c.name for c in CANDIDATES.values()
                    if c.simulated and not isinstance(c.evidence, RunLevelShape) and c.name in supported]
    plant_choice += run_level_choice(evidence)
    plant_choice = sorted(plant_choice, key=lambda c: -float(evidence.set_index("candidate").loc[c, "evidence"]))
    plant_choice = plant_choice[:max_fit]
    for name in plant_choice:
        t1 = time.perf_counter()
        cand = CANDIDATES[name]
        z = float(evidence.set_index("candidate").loc[name, "evidence"])
        # adhesion acts only where fish touch: simulate just the runs with touching pairs
        fit_runs = [r for r in runs if not cand.needs_pairs or len(base_by_run.get(r.id, baseline[0]).pairs)] or runs
        sub = Dataset(dataset.name, dataset.description, dataset.line, dataset.kpi, fit_runs)
        grid: dict[float, dict[str, RunResiduals]] = {}
        values = list(cand.grid)
        for _ in range(2):  # the grid, then once more beyond an end where the error is still falling
            say(f"fit {name}: {', '.join(f'{v:g}' for v in values)} {cand.unit} on {len(fit_runs)} runs")
            # the whole grid at once, so that the workers stay busy to the end
            sims = resimulate_many(dataset.line, fit_runs * len(values),
                                   [cand.params(base, v) for v in values for _ in fit_runs], pool=pool, workers=1)
            for k, v in enumerate(values):
                res = residuals_of(sub, sims[k * len(fit_runs):(k + 1) * len(fit_runs)])
                grid[v] = {r.run_id: r for r in res if r.run_id in base_by_run and not r.error}
                for rid in set(base_by_run) - set(grid[v]):  # a failed simulation counts as no better than the baseline
                    grid[v][rid] = base_by_run[rid]
            values = beyond_the_ends(name, base_by_run, grid)
            if not values:
                break
        fits.append(fit_plant_candidate(name, z, base_by_run, grid, rng))
        timing[f"fit_{name}"] = time.perf_counter() - t1
    for cand in CANDIDATES.values():  # fitted without simulation: cheap, so whenever there is any evidence
        if not cand.simulated:
            z = float(evidence.set_index("candidate").loc[cand.name, "evidence"])
            if z > 0:
                fits.append(fit_drive_candidate(cand, z, drive, rng))

    significant = [f for f in fits if f.significant]
    winner = max(significant, key=lambda f: f.heldout_gain) if significant else None
    cause = winner.name if winner else "none"
    frag = fragment(cause, winner.values if winner else {}, base)

    kpis_before = [compute_kpis(_sim_run(r, s), dataset.line, dataset.kpi) for r, s in zip(runs, base_sims)]
    base_rms = {b.run_id: b.track_rms_m for b in baseline}
    kpis_after, after_rms = kpis_before, base_rms
    if winner is not None and CANDIDATES[cause].simulated:
        t1 = time.perf_counter()
        say(f"confirming {cause} with {winner.values}")
        p = CANDIDATES[cause].params(base, *[winner.values[k] for k in CANDIDATES[cause].parameters])
        sims = resimulate_many(dataset.line, runs, [p] * len(runs), pool=pool, workers=1)
        kpis_after = [compute_kpis(_sim_run(r, s), dataset.line, dataset.kpi) for r, s in zip(runs, sims)]
        after_rms = {b.run_id: b.track_rms_m for b in residuals_of(dataset, sims)}
        timing["confirm"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    if calibration is not None:
        frag = calibration.fragment(calibration.base) + frag
    return Diagnosis(cause, evidence, fits, frag, base_rms, after_rms, kpis_before, kpis_after, timing, baseline, drive,
                     calibration)


def _sim_run(run: Run, resim: Resim) -> Run:
    return Run(run.id, run.hours_post_mortem, "simulated", resim.sim.fish, resim.sim.tracks, resim.sim.photoeyes,
               resim.sim.belts)
