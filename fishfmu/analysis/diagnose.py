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
3. **The model extended** with the named cause (:data:`~fishfmu.analysis.candidates.CANDIDATES`, each candidate's
   own fitter, :mod:`fishfmu.analysis.extension_fit`): its parameters fitted on the calibrated model, with
   intervals and the held-out gain of the extended model.  The result is a scenario fragment.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset, Run
from plant.sim.params import PlantParams

from fishfmu.analysis.calibrate import Calibration, calibrate_with_pool
from fishfmu.analysis.candidate import Terms
from fishfmu.analysis.candidates import CANDIDATES, fragment
from fishfmu.analysis.extension_fit import MIN_GAIN, NOT_CONFIRMED, CandidateFit, FitContext  # noqa: F401 (MIN_GAIN: the report reads it here)
from fishfmu.analysis.levels import FRICTION, RIGOR, run_levels
from fishfmu.analysis.drive_response import drive_residuals_averaged
from fishfmu.analysis.residuals import DRIVE_RESIDUAL_DTYPES, RunResiduals, concat_typed, drop_lags, residuals_of
from fishfmu.analysis.resim import (Resim, drive_check, fish_model_lines, measured_data_plant, pool_for,
                                    refuse_unreplayed, resimulate_many)
from fishfmu.analysis.mismatch import base_mismatch, fit_quality, take_up_law, tracker_noise_m
from fishfmu.analysis.scan import Scan, explained_by, scan
from fishfmu.analysis.scan_tables import scan_tables
from fishfmu.analysis.signatures import ALPHA, Judgement, judge

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
class Diagnosis:
    causes: list[str]
    """The named causes, strongest first (empty: none): the first significant candidate by its signature, each
    further one only if its extension beats, on held-out runs, the model extended with the ones before it."""
    judgement: Judgement
    """Every candidate's covariate test (:mod:`fishfmu.analysis.signatures`): what named the cause."""
    fit: CandidateFit | None
    """The first named cause's model fitted on the calibrated model (None for ``none``)."""
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
    terms: dict[str, float] = field(default_factory=dict)
    """The first named cause's fitted values in its own physical terms
    (:attr:`~fishfmu.analysis.candidate.Candidate.terms`)."""
    further: list[CandidateFit] = field(default_factory=list)
    """Every further significant candidate's extension, fitted on the model extended with the causes before it
    (named when confirmed)."""
    further_terms: dict[str, dict[str, float]] = field(default_factory=dict)
    scan: Scan | None = None
    """The unexplained-discrepancy scan (:mod:`fishfmu.analysis.scan`): what the data follow that no named cause
    explains."""
    rivals: dict[str, str] = field(default_factory=dict)
    """Significant candidates not named because the scan found a dependence that explains their quantity better
    at their location: candidate -> the finding."""
    mismatch: dict = field(default_factory=dict)
    """The calibrated model's mismatch shared by every fish (:func:`fishfmu.analysis.mismatch.base_mismatch`)."""
    quality: dict = field(default_factory=dict)
    """How well the model fits, against the tracker's own noise (:func:`fishfmu.analysis.mismatch.fit_quality`)."""
    take_up: dict = field(default_factory=dict)
    """The base model's take-up law at the transfers (:func:`fishfmu.analysis.mismatch.take_up_law`)."""

    @property
    def unexplained(self) -> list:
        return self.scan.findings if self.scan is not None else []

    @property
    def answer(self) -> str:
        """``named`` (at least one cause; unexplained findings may stand beside it), ``unexplained`` (none named, a
        dependence found that no candidate explains) or ``fits`` (neither: the model fits these runs)."""
        if self.causes:
            return "named"
        return "unexplained" if self.unexplained else "fits"

    @property
    def cause(self) -> str:
        """The named causes joined by ``+``, or ``none``."""
        return "+".join(self.causes) if self.causes else "none"

    @property
    def fits(self) -> list[CandidateFit]:
        return ([self.fit] if self.fit is not None else []) + self.further

    @property
    def not_named(self) -> list[str]:
        """Candidates significant by their signature but not named: their extension did not beat, on held-out runs,
        the model extended with the causes named before them."""
        return [f.name for f in self.further if f.name not in self.causes]

    @property
    def extension(self) -> str:
        """``confirmed`` (the named cause's extension beats the base on held-out runs: the fragment carries it),
        ``not confirmed`` (:data:`~fishfmu.analysis.extension_fit.NOT_CONFIRMED`: the fragment carries it as
        comments only) or ``none`` (no cause named)."""
        if self.fit is None:
            return "none"
        return "confirmed" if self.fit.confirmed else "not confirmed"


def diagnose(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
             progress: Callable[[str], None] | None = None, calibrate: bool = True,
             without: tuple[str, ...] = ()) -> Diagnosis:
    """Name the cause of the discrepancy between the model and the dataset (see the module docstring).
    ``calibrate``: first fit the base model's constants to the dataset (:mod:`fishfmu.analysis.calibrate`); off
    when the base is known to be right (data made by this simulator). ``without``: candidates switched off (a
    cause known not to apply, or the benchmark's open-set check)."""
    refuse_unreplayed(dataset, "diagnose")  # devices it cannot fire: not a fit of the line
    unknown = sorted(set(without) - set(CANDIDATES))
    if unknown:
        raise ValueError(f"--without: no candidate cause named {', '.join(unknown)} (known: {', '.join(CANDIDATES)})")
    with pool_for(workers) as pool:  # kept for every re-simulation below: a new process pays for importing Exudyn
        return _diagnose(dataset, base or measured_data_plant(), pool, seed, progress or (lambda text: None), calibrate,
                         tuple(without))


def simulated_dataset(dataset: Dataset, sims: list[Resim]) -> Dataset:
    """The runs as a re-simulation had them, in the measured-data format (what the measured runs are compared
    with); runs whose re-simulation failed are left out."""
    runs = [Run(r.id, r.hours_post_mortem, r.notes, s.sim.fish, s.sim.tracks, s.sim.photoeyes, s.sim.belts)
            for r, s in zip(dataset.runs, sims) if not s.error]
    return dataset.subset(runs)


def _diagnose(dataset: Dataset, base: PlantParams, pool, seed: int, say: Callable[[str], None],
              calibrate: bool = True, without: tuple[str, ...] = ()) -> Diagnosis:
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    cal = calibrate_with_pool(dataset, base, pool, seed, say, levels=(FRICTION, RIGOR), fit_base=calibrate,
                              heldout_before=False)
    timing["calibration"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    judgement = judge(dataset, rng, simulated_dataset(dataset, cal.sims_after), without)
    timing["judgement"] = time.perf_counter() - t1
    for t in judgement.tests:
        say(f"{t.candidate}: " + (f"p = {t.p_value:.3f}, held-out gain {t.heldout_gain:.1%}, effect {t.effect:.3g}"
                                  if t.judged else t.note))
    t1 = time.perf_counter()
    drive = drive_table(dataset, cal.sims_after)
    timing["drives"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    tables = scan_tables(dataset, judgement.rows, cal.after)
    scan_rng = np.random.default_rng((seed, 41))  # its own stream: the fits draw what they drew before the scan
    explained = {pair for c in judgement.causes for pair in CANDIDATES[c].explains}
    found = scan(tables, scan_rng, explained, ALPHA)
    rivals = _rivals(judgement, found)
    significant_causes = [c for c in judgement.causes if c not in rivals]
    if rivals:  # a rival's quantity is no longer explained: scanned again without the candidate beaten
        explained = {pair for c in significant_causes for pair in CANDIDATES[c].explains}
        found = scan(tables, np.random.default_rng((seed, 41)), explained, ALPHA)
    for c, why in rivals.items():
        say(f"{c}: not named, {why}")
    for f in found.findings:
        say(f"unexplained: {f.text}")
    for f in found.mismatch_findings:
        say(f"the base model's own mismatch: {f.text}")
    timing["scan"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    ctx = FitContext(dataset, cal, drive, pool, rng, say)
    fit = _fit_cause(significant_causes[0], ctx) if significant_causes else None
    further = _fit_further(significant_causes[1:], fit, ctx)
    causes = significant_causes[:1] + [f.name for f in further if f.confirmed]
    timing["fit"] = time.perf_counter() - t1
    confirmed = [f for f in ([fit] if fit is not None else []) + further if f.confirmed]
    if any(CANDIDATES[f.name].acts_on == "plant" for f in confirmed):
        # what the named causes leave: the transfers' lags against the model extended with them, scanned again
        t1 = time.perf_counter()
        say(f"scanning what the model extended with {', '.join(f.name for f in confirmed)} leaves")
        ext = _extended_context(ctx, confirmed).cal.after
        tables = scan_tables(dataset, judgement.rows, ext)
        explained = {pair for c in causes for pair in CANDIDATES[c].explains}
        found = scan(tables, np.random.default_rng((seed, 41)), explained, ALPHA, levels_beside_named=True)
        timing["scan"] += time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    fragment = fish_model_lines(base) + _fragment(cal, base, fit) + "".join(_further_fragment(f, cal) for f in further)
    return Diagnosis(causes, judgement, fit, fragment,
                     {b.run_id: b.track_rms_m for b in cal.baseline}, {b.run_id: b.track_rms_m for b in cal.after},
                     timing, cal.after, drive, cal, run_levels(cal.responses), drop_lag_table(dataset),
                     _terms(fit, cal, dataset), further, {f.name: _terms(f, cal, dataset) for f in further}, found,
                     rivals, base_mismatch(tables, np.random.default_rng((seed, 42))),
                     fit_quality(tables, tracker_noise_m(dataset)), take_up_law(tables, np.random.default_rng((seed, 43))))


def _rivals(judgement: Judgement, found: Scan) -> dict[str, str]:
    """Significant candidates the scan beats at their location: a dependence of the same quantity on a covariate no
    candidate stands for, explaining more of it than the candidate's own term (the issue's rule: a candidate must
    beat the best alternative at its location, not only the constant)."""
    tests = {t.candidate: t for t in judgement.tests}
    stood_for = {pair for c in CANDIDATES.values() if c.name not in judgement.left_out for pair in c.explains}
    out = {}
    for c in judgement.causes:
        own = CANDIDATES[c].explains[0][0] if CANDIDATES[c].explains else None  # the table its test reads
        for f in found.findings:
            beats = f.test.explained > tests[c].explained
            if f.table == own and beats and not explained_by(stood_for, f.table, f.covariate_key):
                out[c] = f"{f.text} explains its quantity better ({f.test.explained:.1%} against {tests[c].explained:.1%})"
                break
    return out


def _fit_cause(cause: str, ctx: FitContext) -> CandidateFit | None:
    """The named cause's model on top of the calibrated one: its parameters and the held-out gain."""
    if cause not in CANDIDATES:
        return None
    cand = CANDIDATES[cause]
    ctx.say(f"fitting {cause} on the calibrated model")
    return cand.fit(cand, ctx)


def _fit_further(names: list[str], first: CandidateFit | None, ctx: FitContext) -> list[CandidateFit]:
    """Each further significant candidate fitted on the calibrated model extended with every cause before it whose
    extension was confirmed (the runs re-simulated with that model first, so its gain is not counted twice)."""
    out: list[CandidateFit] = []
    applied = [first] if first is not None and first.confirmed else []
    for name in names:
        sub = _extended_context(ctx, applied) if applied else ctx
        ctx.say(f"fitting {name} on the calibrated model" + (f" extended with {', '.join(f.name for f in applied)}"
                                                             if applied else ""))
        cand = CANDIDATES[name]
        fit = cand.fit(cand, sub)
        out.append(fit)
        if fit.confirmed:
            applied.append(fit)
    return out


def extended_params(cal: Calibration, fits: list[CandidateFit]) -> PlantParams:
    """The calibrated model with the plant extensions of ``fits`` set (drive and sensor ones leave it unchanged)."""
    p = cal.params
    for f in fits:
        cand = CANDIDATES[f.name]
        if cand.acts_on == "plant" and f.values:
            p = cand.params(p, *[f.values[k] for k in cand.parameters if k in f.values])
    return p


def _extended_context(ctx: FitContext, fits: list[CandidateFit]) -> FitContext:
    """The fitting context with the calibrated model replaced by it extended with ``fits``: every run re-simulated
    with it, so a further cause is judged against what the ones before it already explain."""
    params = extended_params(ctx.cal, fits)
    if params == ctx.cal.params:  # nothing simulated changes (drive causes): the residuals stay
        return ctx
    sims = _every_run_with(ctx, params)
    after = residuals_of(ctx.dataset, sims)
    cal = dataclasses.replace(ctx.cal, params=params, after=after, sims_after=sims)
    return dataclasses.replace(ctx, cal=cal)


def _every_run_with(ctx: FitContext, params: PlantParams) -> list:
    """Every run re-simulated with ``params``, once per model in a diagnosis: a further cause is fitted on the model
    extended with the confirmed causes before it, and the scan afterwards reads that same model again when the
    further cause is not confirmed (the same model and runs give the same re-simulations)."""
    key = params.model_dump_json()
    if key not in ctx.extended_sims:
        runs = ctx.dataset.runs
        ctx.extended_sims[key] = resimulate_many(ctx.dataset.line, runs, [params] * len(runs), pool=ctx.pool,
                                                 workers=1, residuals=True)
    return ctx.extended_sims[key]


def _further_fragment(fit: CandidateFit, cal: Calibration) -> str:
    """A further cause's extension as scenario lines (its own values only; comments when not confirmed)."""
    text = CANDIDATES[fit.name].fragment(fit.values, cal.params) if fit.values else ""
    if fit.confirmed:
        return text
    lo, hi = fit.heldout_gain_ci95
    return (f"# {fit.name}: significant by its signature, its extension not confirmed on top of the causes before it "
            f"(held-out gain {fit.heldout_gain:.1%}, 95 % interval {lo:.1%} to {hi:.1%}); not applied:\n"
            + "".join(line if line.startswith("#") else f"# {line}" for line in text.splitlines(keepends=True)))


def drop_lag_table(dataset: Dataset) -> pd.DataFrame:
    """Per run: hours post mortem, fish dropped alone, and the median of their drop lags [s] (NaN without any)."""
    rows = []
    for run in dataset.runs:
        d = drop_lags(run, dataset.line)["drop_lag_s"]
        rows.append({"run_id": run.id, "hours_post_mortem": run.hours_post_mortem, "drops_alone": len(d),
                     "median_drop_lag_s": float(d.median()) if len(d) else float("nan")})
    return pd.DataFrame(rows)


def setpoints_mps(dataset: Dataset) -> dict[str, float]:
    """Each belt's typical setpoint: the median over the runs' logs of the setpoints it ran at (stopped: left out)."""
    belts = pd.concat([r.belts for r in dataset.runs if len(r.belts)], ignore_index=True) if dataset.runs else None
    if belts is None or belts.empty:
        return {}
    running = belts[belts["setpoint_mps"] > 0.0]
    return {str(c): float(v) for c, v in running.groupby("conveyor_id")["setpoint_mps"].median().items()}


def _terms(fit: CandidateFit | None, cal: Calibration, dataset: Dataset) -> dict[str, float]:
    """The named cause's fitted values in its own terms (run-level effects: about the model their levels were
    simulated around; the others about the calibrated model they extend)."""
    cand = CANDIDATES.get(fit.name) if fit is not None else None
    if cand is None or cand.terms is None or not fit.values:
        return {}
    around = (cal.level_base or cal.params) if cand.level_model else cal.params
    return cand.terms(fit.values, Terms(around, setpoints_mps(dataset)))


def _fragment(cal: Calibration, base: PlantParams, winner: CandidateFit | None) -> str:
    """The calibration and the named cause as one scenario fragment: every value that differs from ``base``."""
    if winner is None:
        return cal.fragment(base) + fragment("none", {}, base)
    extended = CANDIDATES[winner.name].extended_fragment(cal, base, winner)
    if winner.confirmed:
        return extended
    # the cause is named by its signature, but its model does not beat the base on held-out runs: handed over as
    # the calibration alone, the fitted extension kept as comments for whoever wants to try it
    lo, hi = winner.heldout_gain_ci95
    return (cal.fragment(base) + f"# {winner.name}: {NOT_CONFIRMED} (held-out gain {winner.heldout_gain:.1%}, 95 % "
            f"interval {lo:.1%} to {hi:.1%}); the extended model as fitted, not applied:\n"
            + "".join(line if line.startswith("#") else f"# {line}" for line in extended.splitlines(keepends=True)))
