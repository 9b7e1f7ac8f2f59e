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
from fishfmu.analysis.residuals import (DRIVE_RESIDUAL_DTYPES, RunResiduals, concat_typed, drive_residuals_averaged,
                                        drop_lags)
from fishfmu.analysis.resim import Resim, drive_check, pool_for, refuse_unreplayed
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
    terms: dict[str, float] = field(default_factory=dict)
    """The named cause's fitted values in its own physical terms (:attr:`~fishfmu.analysis.candidate.Candidate.terms`)."""

    @property
    def fits(self) -> list[CandidateFit]:
        return [self.fit] if self.fit is not None else []

    @property
    def extension(self) -> str:
        """``confirmed`` (the named cause's extension beats the base on held-out runs: the fragment carries it),
        ``not confirmed`` (:data:`~fishfmu.analysis.extension_fit.NOT_CONFIRMED`: the fragment carries it as
        comments only) or ``none`` (no cause named)."""
        if self.fit is None:
            return "none"
        return "confirmed" if self.fit.confirmed else "not confirmed"


def diagnose(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
             progress: Callable[[str], None] | None = None, calibrate: bool = True) -> Diagnosis:
    """Name the cause of the discrepancy between the model and the dataset (see the module docstring).
    ``calibrate``: first fit the base model's constants to the dataset (:mod:`fishfmu.analysis.calibrate`); off
    when the base is known to be right (data made by this simulator)."""
    refuse_unreplayed(dataset, "diagnose")  # devices it cannot fire: not a fit of the line
    with pool_for(workers) as pool:  # kept for every re-simulation below: a new process pays for importing Exudyn
        return _diagnose(dataset, base or PlantParams(), pool, seed, progress or (lambda text: None), calibrate)


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
    fit = _fit_cause(judgement.cause, FitContext(dataset, cal, drive, pool, rng, say))
    timing["fit"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    return Diagnosis(judgement.cause, judgement, fit, _fragment(cal, base, fit),
                     {b.run_id: b.track_rms_m for b in cal.baseline}, {b.run_id: b.track_rms_m for b in cal.after},
                     timing, cal.after, drive, cal, run_levels(cal.responses), drop_lag_table(dataset),
                     _terms(fit, cal, dataset))


def _fit_cause(cause: str, ctx: FitContext) -> CandidateFit | None:
    """The named cause's model on top of the calibrated one: its parameters and the held-out gain."""
    if cause not in CANDIDATES:
        return None
    cand = CANDIDATES[cause]
    ctx.say(f"fitting {cause} on the calibrated model")
    return cand.fit(cand, ctx)


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
    simulated around)."""
    cand = CANDIDATES.get(fit.name) if fit is not None else None
    if cand is None or cand.terms is None or not fit.values:
        return {}
    return cand.terms(fit.values, Terms(cal.level_base or cal.params, setpoints_mps(dataset)))


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
