"""``fishfmu diagnose``: name the cause of what the simulation gets wrong, fit it, measure the gain.

1. **Calibration** (:mod:`fishfmu.analysis.calibrate`): the constants every line has (one friction level, one
   joint stiffening, the drives' ramps), fitted on the runs with most fish alone, then every run re-simulated
   with them (``--no-calibrate``: the model as given, e.g. data this simulator made).  The fit runs are also
   simulated at a few friction and stiffening levels (:mod:`fishfmu.analysis.levels`), which the run-level
   candidates' models are fitted on afterwards.
2. **Naming** (:mod:`fishfmu.analysis.signatures`): each candidate is a physical quantity that follows a
   covariate; it is tested where physics says the constant model predicts no dependence on that covariate,
   against the constant refitted beside it on held-out runs, with a p-value from shuffling the covariate.  The
   cause is the significant candidate least likely by chance; none significant: ``none``, with what the runs
   cannot decide and what runs would.  Nothing fitted by the calibration can absorb a cause first: the
   calibration holds constants, and the tests compare like with like within the data (adhesion: the measured
   pairs against the same runs' pairs in the calibrated model).
3. **The model extended** with the named cause (:data:`~fishfmu.analysis.candidates.CANDIDATES`): its
   parameters fitted on the calibrated model, with intervals and the held-out gain of the extended model:
   mucus and rigor from the level responses (no more simulation), adhesion and directional friction on a grid
   of simulated strengths, drive droop from the drive logs (linear).  The result is a scenario fragment.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset, Run
from plant.sim.params import PlantParams

from fishfmu.analysis.calibrate import KNOBS, Calibration, calibrate_with_pool
from fishfmu.analysis.candidates import CANDIDATES, Candidate, fragment, plant_tables, plant_value
from fishfmu.analysis.fitting import folds, gain_with_ci, vertex
from fishfmu.analysis.levels import FRICTION, MODELS, RIGOR, ModelFit, Responses, fit_model, gain_over, run_levels
from fishfmu.analysis.residuals import (DRIVE_RESIDUAL_DTYPES, RunResiduals, concat_typed, drive_residuals_averaged,
                                        drop_lags, pair_residuals, residuals_of)
from fishfmu.analysis.resim import refuse_unreplayed, Resim, drive_check, pool_for, resimulate_many
from fishfmu.analysis.signatures import ALPHA, Judgement, judge

MIN_GAIN = 0.02
"""The named cause's fitted model is reported as carrying over to held-out runs when it removes at least this
fraction of their error with its 95 % interval above zero."""

DECISION_RULE = (f"a candidate is significant when its covariate test's p-value is at most {ALPHA:g} (its quantity "
                 "follows its covariate more than shuffling the covariate makes it), the covariate's term beats the "
                 "constant on held-out runs, and its effect is at least the smallest worth naming; the cause is the "
                 "significant candidate with the smallest p-value (ties: the larger lower end of the held-out gain's "
                 "interval); none significant: none")


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


def fit_plant_candidate(name: str, base: dict[str, RunResiduals], grid: dict[float, dict[str, RunResiduals]],
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
    fit = CandidateFit(name, heldout_gain=gain, heldout_gain_ci95=ci, gain_by_run=dict(zip(runs, map(float, u))),
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


def fit_drive_candidate(cand: Candidate, drive: pd.DataFrame, rng: np.random.Generator) -> CandidateFit:
    """Drive droop from the drive residuals, per conveyor's drive: the belt speed lost per newton of load force
    (the drive FMU's ``belt_slip``: creep on the drum under the force that pulls the fish along) and per
    kilogram of fish on the belt (bed friction that grows with the weight carried), fitted together by least
    squares with an offset; linear, so no simulation is needed.  Per drive, because a line's drives differ (a
    droop that is a share of the belt's speed is a different slip on each belt).  ``values``: each drive's
    ``belt_slip[c1]`` and ``droop_per_kg[c1]`` ..., and ``belt_slip`` (their mean over the drives)."""
    fit = CandidateFit(cand.name, error_unit="m/s")
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
    judgement: Judgement
    """Every candidate's covariate test (:mod:`fishfmu.analysis.signatures`): what named the cause."""
    fit: CandidateFit | None
    """The named cause's model fitted on the calibrated model (None for ``none``)."""
    fragment: str
    base_rms_m: dict[str, float]
    """Track RMS per run with the model as given (runs not re-simulated with it: NaN)."""
    after_rms_m: dict[str, float]
    """Track RMS per run with the calibrated model."""
    timing_s: dict[str, float]
    baseline: list[RunResiduals]
    """Every run's residuals against the calibrated model."""
    drive: pd.DataFrame
    calibration: Calibration
    run_levels: pd.DataFrame
    """Each fit run's own best friction and rigor levels, with its hours: the signature of run-level effects."""
    drop_lags: pd.DataFrame = field(default_factory=pd.DataFrame)
    """Per run, the median time a fish dropped alone has lost to the infeed (:func:`drop_lag_table`)."""

    @property
    def fits(self) -> list[CandidateFit]:
        return [self.fit] if self.fit is not None else []


def diagnose(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
             progress: Callable[[str], None] | None = None, calibrate: bool = True) -> Diagnosis:
    """Name the cause of the discrepancy between the model and the dataset (see the module docstring).
    ``calibrate``: first fit the base model's constants to the dataset (:mod:`fishfmu.analysis.calibrate`); off
    when the base is known to be right (data made by this simulator)."""
    refuse_unreplayed(dataset, "diagnose")  # devices it cannot fire: not a fit of the line
    with pool_for(workers) as pool:  # kept for every re-simulation below: a new process pays for importing Exudyn
        return _diagnose(dataset, base or PlantParams(), pool, seed, progress or (lambda text: None), calibrate)


def level_candidate_fit(name: str, model: ModelFit, reference: ModelFit, resp: Responses,
                        rng: np.random.Generator) -> CandidateFit:
    """A run-level candidate's fit from its level model, judged against the constant levels."""
    fit = CandidateFit(name, values=dict(model.values), ci95=dict(model.ci95),
                       error_unit="x noise (the rows it is judged on: lags, drops or photo-eye passages, each "
                                  "over its noise)")
    fit.heldout_gain, fit.heldout_gain_ci95 = gain_over(reference, model, rng)
    fit.gain_by_run = dict(zip(resp.runs, map(float, reference.cv_ss - model.cv_ss)))
    n = max(int(np.count_nonzero(resp.row_weight)), 1)
    fit.heldout_rms_before = float(np.sqrt(reference.cv_ss.sum() / n))
    fit.heldout_rms_after = float(np.sqrt(model.cv_ss.sum() / n))
    return fit


def simulated_dataset(dataset: Dataset, sims: list[Resim]) -> Dataset:
    """The runs as a re-simulation had them, in the measured-data format (what the measured runs are compared
    with); runs whose re-simulation failed are left out."""
    runs = [Run(r.id, r.hours_post_mortem, r.notes, s.sim.fish, s.sim.tracks, s.sim.photoeyes, s.sim.belts)
            for r, s in zip(dataset.runs, sims) if not s.error]
    return dataset.subset(runs)


def _diagnose(dataset: Dataset, base: PlantParams, pool, seed: int, say: Callable[[str], None],
              calibrate: bool = True) -> Diagnosis:
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    cal = calibrate_with_pool(dataset, base, pool, seed, say, levels=(FRICTION, RIGOR), fit_base=calibrate,
                              heldout_before=False)
    timing["calibration"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    judgement = judge(dataset, rng, simulated_dataset(dataset, cal.sims_after))
    timing["judgement"] = time.perf_counter() - t1
    for t in judgement.tests:
        say(f"{t.candidate}: " + (f"p = {t.p_value:.3f}, held-out gain {t.heldout_gain:.1%}, effect {t.effect:.3g}"
                                  if t.judged else t.note))
    t1 = time.perf_counter()
    drive = drive_table(dataset, cal.sims_after)
    fit = _fit_cause(judgement.cause, dataset, cal, drive, pool, rng, say)
    timing["fit"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    return Diagnosis(judgement.cause, judgement, fit, _fragment(cal, base, fit),
                     {b.run_id: b.track_rms_m for b in cal.baseline}, {b.run_id: b.track_rms_m for b in cal.after},
                     timing, cal.after, drive, cal, run_levels(cal.responses), drop_lag_table(dataset))


def _fit_cause(cause: str, dataset: Dataset, cal: Calibration, drive: pd.DataFrame, pool,
               rng: np.random.Generator, say: Callable[[str], None]) -> CandidateFit | None:
    """The named cause's model on top of the calibrated one: its parameters and the held-out gain."""
    if cause not in CANDIDATES:
        return None
    cand = CANDIDATES[cause]
    say(f"fitting {cause} on the calibrated model")
    if cand.level_model is not None:  # judged on the rows its levels change, against the constant levels there
        on = cal.responses.only(MODELS[cand.level_model].kinds)
        return level_candidate_fit(cause, fit_model(MODELS[cand.level_model], on, rng),
                                   fit_model(MODELS["constant"], on, rng), on, rng)
    if cand.acts_on == "drive":
        return fit_drive_candidate(cand, drive, rng)
    # fitted on a grid of simulated strengths: on the runs with touching pairs (adhesion) or the fit runs
    cur_by_run = {b.run_id: b for b in cal.after if not b.error}
    if cand.needs_pairs:
        runs = [r for r in dataset.runs if r.id in cur_by_run and len(pair_residuals(r, r.tracks, dataset.line))]
    else:
        runs = [r for r in dataset.runs if r.id in set(cal.fit_runs)]
    return _fit_on_grid(dataset, cand, cal.params, cur_by_run, runs, pool, rng, say)


def drop_lag_table(dataset: Dataset) -> pd.DataFrame:
    """Per run: hours post mortem, fish dropped alone, and the median of their drop lags [s] (NaN without any)."""
    rows = []
    for run in dataset.runs:
        d = drop_lags(run, dataset.line)["drop_lag_s"]
        rows.append({"run_id": run.id, "hours_post_mortem": run.hours_post_mortem, "drops_alone": len(d),
                     "median_drop_lag_s": float(d.median()) if len(d) else float("nan")})
    return pd.DataFrame(rows)


def _fit_on_grid(dataset: Dataset, cand: Candidate, params: PlantParams, cur_by_run: dict[str, RunResiduals],
                 fit_runs: list, pool, rng: np.random.Generator, say: Callable[[str], None]) -> CandidateFit:
    """A candidate at its grid of strengths on ``fit_runs``, extended once beyond an end where the error still
    falls, against the calibrated model (``cur_by_run``: its residuals)."""
    fit_runs = [r for r in fit_runs if r.id in cur_by_run]
    if not fit_runs:  # nothing carries its signal: no gain either way
        return CandidateFit(cand.name, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="m")
    sub = dataset.subset(fit_runs)
    base_by_run = {r.id: cur_by_run[r.id] for r in fit_runs}
    grid: dict[float, dict[str, RunResiduals]] = {}
    values = list(cand.grid)
    for _ in range(2):
        say(f"fit {cand.name}: {', '.join(f'{v:g}' for v in values)} {cand.unit} on {len(fit_runs)} runs")
        sims = resimulate_many(dataset.line, fit_runs * len(values),
                               [cand.params(params, v) for v in values for _ in fit_runs], pool=pool, workers=1,
                               residuals=True)
        for k, v in enumerate(values):
            res = residuals_of(sub, sims[k * len(fit_runs):(k + 1) * len(fit_runs)])
            grid[v] = {r.run_id: r for r in res if r.run_id in base_by_run and not r.error}
            for rid in set(base_by_run) - set(grid[v]):  # a failed simulation counts as no better than the base
                grid[v][rid] = base_by_run[rid]
        values = beyond_the_ends(cand.name, base_by_run, grid)
        if not values:
            break
    return fit_plant_candidate(cand.name, base_by_run, grid, rng)


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
    # a run-level effect comes with its own constant levels (fitted with it), around the model the levels were
    # simulated about
    p = cal.level_base.model_copy(deep=True)
    FRICTION.apply(p, winner.values["friction_level"], 0.0)
    RIGOR.apply(p, winner.values.get("joint_stiffening", 0.0), 0.0)
    cand.apply(p, *[winner.values[k] for k in cand.parameters])
    paths = [path for k in KNOBS.values() for path in k.writes] + list(cand.writes)
    changed = {path: plant_value(p, path) for path in dict.fromkeys(paths) if plant_value(p, path) != plant_value(base, path)}
    return (f"# fitted by fishfmu diagnose on the runs {', '.join(cal.fit_runs)}: the calibrated model and "
            f"{cand.description}\n" + plant_tables(changed) + cal.drive_fragment())
