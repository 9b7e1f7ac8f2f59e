"""``fishfmu diagnose``: name the cause of what the simulation gets wrong, fit it, measure the gain.

Every candidate is fitted; cheap evidence (:mod:`fishfmu.analysis.evidence`) is shown beside the fits as an
explanation, never as a gate.  The pipeline fits in minutes on a 2-core machine because each candidate is
fitted on the runs that carry its signal, mostly from simulations it shares with the others:

1. **Calibration** (:mod:`fishfmu.analysis.calibrate`): every run re-simulated with the model as given;
   the runs with most fish alone are the fit runs; the friction gradient along a fish is fitted on them
   (``--no-calibrate``: not fitted), then each fit run is simulated at two more friction levels and two
   rigor levels (:mod:`fishfmu.analysis.levels`: the fish's lags and the photo-eyes' blocked shares), and
   the constant friction level and joint stiffening fitted from those responses.
2. **Run-level candidates** (mucus friction, rigor): models of the runs' levels against hours post
   mortem, fitted on the level responses without more simulation; each run's error with parameters
   chosen on the other runs (leave one run out) against that of the constant levels (the calibrated
   model).  The other runs are then re-simulated with the calibrated model, or, when a run-level
   candidate is significant, with its levels for each run's hours: what it explains in them is not left
   for adhesion to explain (fresh, slippery fish part from a neighbour late, as sticky ones do).
3. **Adhesion**: the runs with touching pairs simulated at a few attraction forces on top of that model;
   the extra separation of close pairs, held-out by folds of runs.
4. **Drive droop**: from the drive logs against the simulated belt loads, no simulation (linear).
5. **Decision**: a candidate is *significant* when it removes at least ``MIN_GAIN`` of its held-out error
   and the 95 % interval of that gain (a bootstrap over runs) is above zero; of the significant ones, the
   cause is the one whose interval's lower end is highest (the most certain; gains of different
   candidates are fractions of different residuals).  None significant: ``none``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.measured import Dataset, Run
from plant.params import PlantParams

from fishfmu.analysis.calibrate import KNOBS, Calibration, calibrate_with_pool
from fishfmu.analysis.candidates import CANDIDATES, Candidate, fragment, plant_tables, plant_value
from fishfmu.analysis.evidence import evidence_table
from fishfmu.analysis.fitting import folds, gain_with_ci, vertex
from fishfmu.analysis.levels import (FRICTION, MODELS, RIGOR, LevelModel, ModelFit, Responses, fit_model, gain_over,
                                     run_levels)
from fishfmu.analysis.residuals import (BELT_RESIDUAL_DTYPES, DRIVE_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES,
                                        RunResiduals, concat_typed, drive_residuals_averaged, drop_lags,
                                        pair_residuals, residuals_of)
from fishfmu.analysis.resim import Resim, drive_check, pool_for, resimulate_many

MIN_GAIN = 0.02
"""A cause must remove at least this fraction of the held-out error (and its 95 % interval must be above
zero): measurement noise that no model removes can be most of the error, as with noisy drive logs."""

DECISION_RULE = (f"every candidate is fitted; significant = held-out gain >= {MIN_GAIN:.0%} of its residuals' "
                 "held-out error with the 95 % bootstrap interval (over runs) above zero; adhesion is judged on top "
                 "of a significant run-level effect (mucus, rigor); the cause is the significant candidate with the "
                 "highest lower end of that interval; none significant: none")


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
    gain_by_run: dict[str, float] = field(default_factory=dict)
    """Held-out error each run's residuals lose with the candidate (in the squares of ``error_unit``)."""

    @property
    def significant(self) -> bool:
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
            # the simulated strength nearest the vertex of the other folds' error curve (a held-out run is scored
            # where it was simulated; the bare minimum of a coarse grid would pick an erratic point whole)
            fitted = vertex(values, ss[g][:, ~test].sum(axis=1) / np.maximum(nn[g][:, ~test].sum(axis=1), 1))
            best = int(np.argmin(np.abs(values - fitted)))
            u[test] += ss[g][0, test] - ss[g][best, test]
            e0[test] += ss[g][0, test]
    gain, ci = gain_with_ci(u, e0, rng)
    n_total = sum(nn[g][0].sum() for g in groups)
    fit = CandidateFit(name, z, heldout_gain=gain, heldout_gain_ci95=ci, gain_by_run=dict(zip(runs, map(float, u))),
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
    """Drive droop from the drive residuals, per conveyor's drive: the belt speed lost per newton of load force
    (the drive FMU's ``belt_slip``: creep on the drum under the force that pulls the fish along) and per
    kilogram of fish on the belt (bed friction that grows with the weight carried), fitted together by least
    squares with an offset; linear, so no simulation is needed.  Per drive, because a line's drives differ (a
    droop that is a share of the belt's speed is a different slip on each belt).  ``values``: each drive's
    ``belt_slip[c1]`` and ``droop_per_kg[c1]`` ..., and ``belt_slip`` (their mean over the drives)."""
    fit = CandidateFit(cand.name, z, error_unit="m/s")
    (pname,) = cand.parameters
    lo, hi = cand.bounds
    d = drive.dropna(subset=["residual_mps", "load_force_n"])
    if "load_mass_kg" not in d:
        d = d.assign(load_mass_kg=0.0)
    d = d.fillna({"load_mass_kg": 0.0})
    runs = sorted(d["run_id"].unique())
    conveyors = sorted(d["conveyor_id"].unique())
    if len(runs) < 2:
        return fit

    def slopes(rows: pd.DataFrame) -> dict[str, tuple[float, float]]:
        """(speed lost per N, per kg) of each drive: least squares with an offset, a regressor without spread left out."""
        out = {}
        for c in conveyors:
            rc = rows[rows["conveyor_id"] == c]
            cols = [k for k in ("load_force_n", "load_mass_kg") if len(rc) >= 4 and np.std(rc[k]) > 1e-9]
            coef = dict.fromkeys(("load_force_n", "load_mass_kg"), 0.0)
            if cols:
                a = np.column_stack([np.ones(len(rc))] + [rc[k].to_numpy(float) for k in cols])
                sol = np.linalg.lstsq(a, rc["residual_mps"].to_numpy(float), rcond=None)[0]
                coef.update({k: -float(v) for k, v in zip(cols, sol[1:])})
            out[c] = (float(np.clip(coef["load_force_n"], lo, hi)), float(np.clip(coef["load_mass_kg"], 0.0, 0.05)))
        return out

    def after(rows: pd.DataFrame, s: dict[str, tuple[float, float]]) -> np.ndarray:
        per_n = rows["conveyor_id"].map({c: v[0] for c, v in s.items()}).to_numpy(float)
        per_kg = rows["conveyor_id"].map({c: v[1] for c, v in s.items()}).to_numpy(float)
        return (rows["residual_mps"].to_numpy() + per_n * rows["load_force_n"].to_numpy()
                + per_kg * rows["load_mass_kg"].to_numpy())

    u, e0 = np.zeros(len(runs)), np.zeros(len(runs))
    for fold in folds(runs):
        s = slopes(d[~d["run_id"].isin(fold)])
        for j, r in enumerate(runs):
            if r in fold:
                rr = d[d["run_id"] == r]
                # the offset of each drive is no droop: it is the same with and without the candidate
                base = rr["residual_mps"].to_numpy() - rr.groupby("conveyor_id")["residual_mps"].transform("mean").to_numpy()
                moved = after(rr, s)
                moved = moved - pd.Series(moved, index=rr.index).groupby(rr["conveyor_id"]).transform("mean").to_numpy()
                e0[j] = float(np.sum(base**2))
                u[j] = e0[j] - float(np.sum(moved**2))
    fit.heldout_gain, fit.heldout_gain_ci95 = gain_with_ci(u, e0, rng)
    fit.gain_by_run = dict(zip(runs, map(float, u)))
    fit.heldout_rms_before = float(np.sqrt(e0.sum() / len(d)))
    fit.heldout_rms_after = float(np.sqrt(max(e0.sum() - u.sum(), 0.0) / len(d)))
    per = slopes(d)
    boot = [slopes(pd.concat([d[d["run_id"] == runs[i]] for i in rng.integers(0, len(runs), len(runs))]))
            for _ in range(200)]
    fit.values[pname] = float(np.mean([v[0] for v in per.values()]))
    fit.ci95[pname] = tuple(float(np.percentile([np.mean([v[0] for v in b.values()]) for b in boot], q))
                            for q in (2.5, 97.5))
    for c in conveyors:
        for k, key in ((0, f"{pname}[{c}]"), (1, f"droop_per_kg[{c}]")):
            fit.values[key] = per[c][k]
            fit.ci95[key] = tuple(float(np.percentile([b[c][k] for b in boot], q)) for q in (2.5, 97.5))
    return fit


@dataclass
class Diagnosis:
    cause: str
    evidence: pd.DataFrame
    fits: list[CandidateFit]
    fragment: str
    base_rms_m: dict[str, float]
    """Track RMS per run with the model as given."""
    after_rms_m: dict[str, float]
    """Track RMS per run with the calibrated model (the fit runs: gradient only, friction level 1)."""
    timing_s: dict[str, float]
    baseline: list[RunResiduals]
    """Every run's residuals against the calibrated model: what the candidates are judged against."""
    drive: pd.DataFrame
    calibration: Calibration
    run_levels: pd.DataFrame
    """The signature of run-level effects: each fit run's own best friction and rigor levels, with its hours."""
    drop_lags: pd.DataFrame = field(default_factory=pd.DataFrame)
    """The same read from the data alone: per run, the median time a fish dropped alone has lost to the infeed
    (:func:`fishfmu.analysis.residuals.drop_lags`), with its hours and how many drops of a fish alone it has."""

    def ranking(self) -> list[str]:
        fitted = sorted(self.fits, key=lambda f: -np.nan_to_num(f.heldout_gain_ci95[0], nan=-1.0))
        rest = [c for c in self.evidence["candidate"] if c not in {f.name for f in fitted}]
        return [f.name for f in fitted] + rest


def diagnose(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
             progress: Callable[[str], None] | None = None, calibrate: bool = True) -> Diagnosis:
    """Name the cause of the discrepancy between the model and the dataset (see the module docstring).
    ``calibrate``: first fit the base model to the dataset (:mod:`fishfmu.analysis.calibrate`) and judge
    the candidates against it; off when the base is known to be right (data made by this simulator)."""
    with pool_for(workers) as pool:  # kept for every re-simulation below: a new process pays for importing Exudyn
        return _diagnose(dataset, base or PlantParams(), pool, seed, progress or (lambda text: None), calibrate)


def level_params(level_base: PlantParams, model: LevelModel, values: dict[str, float], hours: float) -> PlantParams:
    """The parameters of a run ``hours`` post mortem under a run-level model with these fitted values."""
    levels = model.levels(np.array([hours]), *[values[k] for k in model.parameters])
    p = FRICTION.params(level_base, float(levels["friction"][0]), hours)
    RIGOR.apply(p, float(levels["rigor"][0]), hours)
    return p


def level_candidate_fit(name: str, z: float, model: ModelFit, reference: ModelFit, resp: Responses,
                        rng: np.random.Generator) -> CandidateFit:
    """A run-level candidate's fit from its level model, judged against the constant friction level."""
    fit = CandidateFit(name, z, values=dict(model.values), ci95=dict(model.ci95),
                       error_unit="x noise (the rows it is judged on: lags, drops or photo-eye passages, each "
                                  "over its noise)")
    fit.heldout_gain, fit.heldout_gain_ci95 = gain_over(reference, model, rng)
    fit.gain_by_run = dict(zip(resp.runs, map(float, reference.cv_ss - model.cv_ss)))
    n = max(int(np.count_nonzero(resp.row_weight)), 1)
    fit.heldout_rms_before = float(np.sqrt(reference.cv_ss.sum() / n))
    fit.heldout_rms_after = float(np.sqrt(model.cv_ss.sum() / n))
    return fit


def _diagnose(dataset: Dataset, base: PlantParams, pool, seed: int, say: Callable[[str], None],
              calibrate: bool = True) -> Diagnosis:
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    # candidates simulated on a grid of their own (adhesion) start in the batch of the held-out runs'
    # calibrated re-simulation, on the held-out runs where the measurement shows touching pairs
    grid_cands = [c for c in CANDIDATES.values() if c.grid]
    grid_runs: dict[str, list] = {}
    level_fits: list[CandidateFit] = []
    applied: dict[str, Callable[[Run], PlantParams]] = {}

    def first_grid(params_of: Callable[[Run], PlantParams], held: list) -> list:
        jobs = []
        for cand in grid_cands:
            grid_runs[cand.name] = [r for r in held if not cand.needs_pairs
                                    or len(pair_residuals(r, r.tracks, dataset.line))]
            jobs += [(r, cand.params(params_of(r), v)) for v in cand.grid for r in grid_runs[cand.name]]
        applied["params_of"] = params_of
        return jobs

    def run_level_effect(resp: Responses, level_base: PlantParams) -> Callable[[Run], PlantParams] | None:
        """Fit the run-level candidates on the fit runs' responses; when one is significant, the held-out runs are
        simulated with its levels, so that what it explains is not left for adhesion to explain."""
        for cand in CANDIDATES.values():
            if cand.level_model is not None:  # judged on the rows its levels change, against the constant levels there
                on = resp.only(MODELS[cand.level_model].kinds)
                reference = fit_model(MODELS["constant"], on, rng)
                model = fit_model(MODELS[cand.level_model], on, rng)
                level_fits.append(level_candidate_fit(cand.name, z_of.get(cand.name, 0.0), model, reference, on, rng))
        best = max((f for f in level_fits if f.significant), key=lambda f: f.heldout_gain_ci95[0], default=None)
        if best is None:
            return None
        say(f"held-out runs judged with {best.name} (held-out gain on the fit runs {best.heldout_gain:.0%}, "
            f"{best.heldout_gain_ci95[0]:.0%} to {best.heldout_gain_ci95[1]:.0%})")
        return lambda run: level_params(level_base, MODELS[CANDIDATES[best.name].level_model], best.values,
                                        run.hours_post_mortem if run.hours_post_mortem is not None else 24.0)

    z_of: dict[str, float] = {}
    cal = calibrate_with_pool(dataset, base, pool, seed, say, levels=(FRICTION, RIGOR), fit_base=calibrate,
                              heldout_before=False, extra=first_grid, heldout_levels=run_level_effect)
    timing["calibration"] = time.perf_counter() - t0
    sims = cal.sims_after
    current = cal.after
    drive = drive_table(dataset, sims)
    rows = concat_typed([b.rows for b in current], BELT_RESIDUAL_DTYPES)
    pairs = concat_typed([b.pairs for b in current], PAIR_RESIDUAL_DTYPES)
    evidence = evidence_table(rows, pairs, drive, seed)
    z_of.update(evidence.set_index("candidate")["evidence"].astype(float).to_dict())
    for f in level_fits:  # fitted before the evidence was at hand
        f.evidence_z = z_of.get(f.name, 0.0)
    say("evidence (an explanation, not a gate): " + ", ".join(f"{c} z={z:.1f}" for c, z in z_of.items()))

    fits: list[CandidateFit] = list(level_fits)
    resp = cal.responses
    t1 = time.perf_counter()
    cur_by_run = {b.run_id: b for b in current if not b.error}
    done = iter(cal.extra_sims)
    for cand in grid_cands:  # simulated on the runs that carry its signal (adhesion: runs with touching pairs)
        first = {v: [next(done) for _ in grid_runs[cand.name]] for v in cand.grid}
        fits.append(_fit_on_grid(dataset, cand, applied["params_of"], cur_by_run, grid_runs[cand.name], first,
                                 z_of.get(cand.name, 0.0), pool, rng, say))
        timing[f"fit_{cand.name}"] = time.perf_counter() - t1
    for cand in CANDIDATES.values():  # fitted without simulation
        if cand.acts_on == "drive":
            fits.append(fit_drive_candidate(cand, z_of.get(cand.name, 0.0), drive, rng))

    significant = [f for f in fits if f.significant]
    winner = max(significant, key=lambda f: f.heldout_gain_ci95[0]) if significant else None
    cause = winner.name if winner else "none"
    frag = _fragment(cal, base, winner)
    timing["total"] = time.perf_counter() - t0
    return Diagnosis(cause, evidence, fits, frag, {b.run_id: b.track_rms_m for b in cal.baseline},
                     {b.run_id: b.track_rms_m for b in current}, timing, current, drive, cal, run_levels(resp),
                     drop_lag_table(dataset))


def drop_lag_table(dataset: Dataset) -> pd.DataFrame:
    """Per run: hours post mortem, fish dropped alone, and the median of their drop lags [s] (NaN without any)."""
    rows = []
    for run in dataset.runs:
        d = drop_lags(run, dataset.line)["drop_lag_s"]
        rows.append({"run_id": run.id, "hours_post_mortem": run.hours_post_mortem, "drops_alone": len(d),
                     "median_drop_lag_s": float(d.median()) if len(d) else float("nan")})
    return pd.DataFrame(rows)


def _fit_on_grid(dataset: Dataset, cand: Candidate, params_of: Callable[[Run], PlantParams],
                 cur_by_run: dict[str, RunResiduals],
                 fit_runs: list, first: dict[float, list], z: float, pool, rng: np.random.Generator,
                 say: Callable[[str], None]) -> CandidateFit:
    """A candidate at its grid of strengths (``first``: the grid's re-simulations of ``fit_runs``, done), extended
    once beyond an end where the error still falls, against the calibrated model."""
    fit_runs = [r for r in fit_runs if r.id in cur_by_run]
    if not fit_runs:  # nothing carries its signal: no gain either way
        return CandidateFit(cand.name, z, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="m")
    sub = Dataset(dataset.name, dataset.description, dataset.line, dataset.kpi, fit_runs)
    base_by_run = {r.id: cur_by_run[r.id] for r in fit_runs}
    grid: dict[float, dict[str, RunResiduals]] = {}
    pending = dict(first)
    for _ in range(2):
        for v, sims in pending.items():
            res = residuals_of(sub, sims)
            grid[v] = {r.run_id: r for r in res if r.run_id in base_by_run and not r.error}
            for rid in set(base_by_run) - set(grid[v]):  # a failed simulation counts as no better than the base
                grid[v][rid] = base_by_run[rid]
        values = beyond_the_ends(cand.name, base_by_run, grid)
        if not values:
            break
        say(f"fit {cand.name}: {', '.join(f'{v:g}' for v in values)} {cand.unit} on {len(fit_runs)} runs")
        sims = resimulate_many(dataset.line, fit_runs * len(values),
                               [cand.params(params_of(r), v) for v in values for r in fit_runs], pool=pool, workers=1,
                               residuals=True)
        pending = {v: sims[k * len(fit_runs):(k + 1) * len(fit_runs)] for k, v in enumerate(values)}
    return fit_plant_candidate(cand.name, z, base_by_run, grid, rng)


def _fragment(cal: Calibration, base: PlantParams, winner: CandidateFit | None) -> str:
    """The calibration and the named cause as one scenario fragment: every value that differs from ``base``."""
    if winner is None:
        return cal.fragment(base) + fragment("none", {}, base)
    cand = CANDIDATES[winner.name]
    if cand.acts_on == "drive":  # one value per drive instance
        slip = {k[k.index("[") + 1:-1]: v for k, v in winner.values.items() if k.startswith(f"{cand.writes[0]}[")}
        per_kg = {k[k.index("[") + 1:-1]: v for k, v in winner.values.items() if k.startswith("droop_per_kg[")}
        return cal.fragment(base) + f"# fitted by fishfmu diagnose: {cand.description}\n" + "".join(
            f"# in the conveyor_drive FMU instance driving {c}:\n# [fmu.parameters]\n# {cand.writes[0]} = {v:.4g}\n"
            + (f"# and {per_kg[c] * 1e3:.3g} mm/s lost per kg of fish on the belt (the drive FMU has no input for the "
               "mass carried: this part is reported, not modelled)\n" if per_kg.get(c, 0.0) > 0.0 else "")
            for c, v in slip.items())
    if cand.level_model is None:
        return cal.fragment(base) + cand.fragment(winner.values, cal.params)
    # a run-level effect comes with its own friction level (fitted with it), on the calibrated gradient
    p = cal.level_base.model_copy(deep=True)
    FRICTION.apply(p, winner.values["friction_level"], 0.0)
    RIGOR.apply(p, winner.values.get("joint_stiffening", 0.0), 0.0)
    cand.apply(p, *[winner.values[k] for k in cand.parameters])
    paths = [path for k in KNOBS.values() for path in k.writes] + list(cand.writes)
    changed = {path: plant_value(p, path) for path in dict.fromkeys(paths) if plant_value(p, path) != plant_value(base, path)}
    return (f"# fitted by fishfmu diagnose on the runs {', '.join(cal.fit_runs)}: the calibrated model and "
            f"{cand.description}\n" + plant_tables(changed) + cal.drive_fragment())
