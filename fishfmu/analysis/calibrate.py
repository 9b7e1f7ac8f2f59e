"""``fishfmu calibrate``: fit the constants every line has and nobody knows exactly, before any effect is
judged.

A measured line differs from its model in ways no hidden effect explains: real friction between fish and a
belt is not the table's 0.45, and fish are not exactly as stiff as the paper's rag-doll.  The calibration fits
**constants only**: one friction level (fish-belt and fish-guide), one joint stiffening, and each drive's ramp.
Nothing that varies with what a candidate cause varies with (hours post mortem, the fish's direction, the load,
contact between fish) is a knob, so the calibration cannot absorb a cause before it is judged
(:mod:`fishfmu.analysis.signatures` judges them): an earlier version also fitted how friction differs along a
fish, a kind of direction-dependent friction, and took the asymmetry that directional friction makes.

1. **Fit runs.** The runs with the most fish riding alone (at least half of the runs; chosen from the measured
   tracks, not from names or notes).  The others are held out: the calibration never sees them, and their error
   before and after is the check that it generalises.
2. **Baseline**: every run re-simulated with the model as given.
3. **Levels** (:mod:`fishfmu.analysis.levels`): the fit runs at two more friction levels (belts and guides;
   ``diagnose`` adds two joint-stiffening levels), extended past an end where a run's own best level still lies;
   the constant level(s) that fit every run are the calibration.
4. Every value gets a 95 % interval (bootstrap over the fit runs) and a held-out gain (each fit run scored with
   values chosen on the others); it is applied only if that gain's interval is above zero and the value is
   physically plausible (:data:`PLAUSIBLE`); one that is not is reported as a finding and not applied: it
   fits, but stands for something the model lacks rather than the quantity it names.  The held-out runs are
   then re-simulated with the calibrated model.
5. The drives' ramps, from the start-ups in their logs, without simulating fish
   (:mod:`fishfmu.analysis.drive_response`), judged the same way.

The result is a scenario fragment (``calibrated.toml``: ``[plant]`` tables, the drives' ramps as comments) that
``fishfmu compare`` and ``diagnose`` take with ``--scenario`` (and whose tables a scenario for ``run`` can take).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from plant.errors import SimulationError
from plant.contract.measured import Dataset, Run
from plant.fish.population import DEFAULT_HOURS_POST_MORTEM
from plant.sim.params import PlantParams

from fishfmu.analysis.fragments import plant_tables, plant_value
from fishfmu.analysis.drive_response import DriveResponseFit, fit_drive_responses
from fishfmu.analysis.fitting import gain_with_ci
from fishfmu.analysis.levels import FRICTION, MODELS, RIGOR, Level, Responses, fit_model, responses, run_levels
from fishfmu.analysis.residuals import (BELT_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES, RunResiduals, alone,
                                        belt_residuals, residuals_of, track_errors, typed_frame)
from fishfmu.analysis.resim import measured_data_plant, refuse_unreplayed, pool_for, resimulate_many


@dataclass(frozen=True)
class Knob:
    """A base parameter of the line, as a change of the model's value, fitted on some residuals."""

    name: str
    description: str
    off: float
    """The change that leaves the model as it is (1 for a multiplier, 0 for an offset)."""
    grid: tuple[float, ...]
    """Changes simulated besides ``off``."""
    bounds: tuple[float, float]
    group: str | None
    """The residuals it is fitted on (:meth:`~fishfmu.analysis.fitting.RunResiduals.squares`)."""
    apply: Callable[[PlantParams, float], None]
    writes: tuple[str, ...]
    """Dotted paths in ``[plant]`` it changes: the fragment is these, read back."""


def _friction(p: PlantParams, m: float) -> None:
    FRICTION.apply(p, m, 0.0)


def _stiffening(p: PlantParams, k: float) -> None:
    p.joints.stiffening = float(k)


KNOBS: dict[str, Knob] = {k.name: k for k in (
    Knob("friction_level", "fish-belt and fish-guide friction coefficients (multiplier)", 1.0, FRICTION.grid,
         FRICTION.bounds, "transfers", _friction, ("friction.fish_belt", "friction.fish_guide")),
    Knob("joint_stiffening", "every fish's joints (1 + k) x stiffer, with the range lost that goes with it (diagnose "
         "only: it needs the rigor level's simulations)", 0.0, RIGOR.grid, RIGOR.bounds, "transfers", _stiffening,
         ("joints.stiffening",)),
)}
"""The knobs: constants, fitted together through the level responses of :mod:`fishfmu.analysis.levels` (the same
simulations that fit mucus and rigor in ``diagnose``)."""

PLAUSIBLE: dict[str, tuple[float, float, str]] = {  # dotted path in [plant] -> (low, high, why)
    "friction.fish_belt": (0.2, 0.9, "wet fish skin on a conveyor belt: about 0.3-0.7 is measured for fish on "
                                     "plastic belts; outside 0.2-0.9 it is no friction coefficient"),
    "friction.fish_guide": (0.1, 0.9, "fish skin on a stainless or plastic guide"),
    "joints.stiffening": (-0.5, 10.0, "a dead fish's joints (before any rigor): more than 11 times the paper's "
                                      "rag-doll stiffness is a fish in rigor, not a constant"),
}
"""A calibrated value outside these ranges is not applied but reported as a finding: it fits the data best, but
stands more likely for something the model lacks than for the quantity it names, and a model carrying it would
be the wrong base to judge the candidate causes against."""


@dataclass
class KnobFit:
    name: str
    value: float = float("nan")
    """The change applied (a multiplier or an offset of the model's value, see :class:`Knob`): the fitted one,
    or half of it when the whole made the held-out runs worse."""
    fitted: float = float("nan")
    """The change with the least error on the fit runs (``ci95`` is its interval)."""
    ci95: tuple[float, float] = (float("nan"), float("nan"))
    heldout_gain: float = float("nan")
    """Fraction of the fit runs' error (of its residuals) removed when the value is chosen on the other folds."""
    heldout_gain_ci95: tuple[float, float] = (float("nan"), float("nan"))
    kept: bool = False
    """Applied to the calibrated model: its held-out gain interval is above zero, and with it the held-out
    runs are not worse."""
    rejected_on_heldout: bool = False
    """Its gain on the fit runs was clear, but the held-out runs got worse with it."""
    implausible: list[str] = field(default_factory=list)
    """Findings: the values it would give outside :data:`PLAUSIBLE` (then it is not applied)."""
    errors: dict[float, float] = field(default_factory=dict)
    """Mean square error of its residuals [m^2] per simulated change (fit runs)."""


@dataclass
class Calibration:
    base: PlantParams
    """The model it started from."""
    params: PlantParams
    """The calibrated model."""
    fits: list[KnobFit]
    fit_runs: list[str]
    heldout_runs: list[str]
    rms_before_m: dict[str, float]
    """Per group of runs (``fit``, ``heldout``, ``all``): RMS of the lags of fish alone, model as given."""
    rms_after_m: dict[str, float]
    """The same, calibrated (fit runs: interpolated in the level responses, not simulated at the fitted level)."""
    track_rms_before_m: dict[str, float]
    track_rms_after_m: dict[str, float]
    timing_s: dict[str, float]
    baseline: list[RunResiduals]
    after: list[RunResiduals]
    """Every run against the calibrated model (fit runs: at the levels' simulated value off, the model as given;
    their calibrated errors are interpolated in the responses)."""
    responses: Responses | None = None
    """How the fit runs' residuals move with the levels (friction, and rigor when asked for)."""
    level_base: PlantParams | None = None
    """The model the levels were simulated around (the model as given)."""
    sims_after: list = field(default_factory=list, repr=False)
    """Every run re-simulated (:class:`~fishfmu.analysis.resim.Resim`), in the dataset's order: the held-out
    runs with the calibrated model, the fit runs with every level off (the base of the responses)."""
    drives: list[DriveResponseFit] = field(default_factory=list)
    """Each drive's ramp, fitted on the start-ups in its log (:mod:`fishfmu.analysis.drive_response`)."""

    def changed(self, base: PlantParams) -> dict[str, tuple[float, float]]:
        """Every value the calibration changed: dotted path -> (model's, calibrated)."""
        out = {}
        for f in self.fits:
            for path in KNOBS[f.name].writes:
                a, b = plant_value(base, path), plant_value(self.params, path)
                if a != b:
                    out[path] = (a, b)
        return out

    def fragment(self, base: PlantParams) -> str:
        """The calibrated values as a scenario fragment (TOML, ``[plant]`` tables only)."""
        changed = self.changed(base)
        head = "# fitted by fishfmu calibrate on the runs " + ", ".join(self.fit_runs) + "\n"
        if not changed:
            return (head + "# no [plant] value changed: no base parameter fitted the data clearly better than the "
                    "model's\n" + self.drive_fragment())
        return head + plant_tables({path: value for path, (_, value) in changed.items()}) + self.drive_fragment()

    def drive_fragment(self) -> str:
        """The drives' fitted ramps, as comments: a drive is an FMU of the scenario, not part of ``[plant]``."""
        kept = [d for d in self.drives if d.kept]
        if not kept:
            return ""
        return "# the drives' ramps, fitted on the start-ups in the drive logs (built-in conveyor_drive FMU):\n" + "".join(
            f"# in the instance driving {d.conveyor_id}: [fmu.parameters] ramp_acceleration = {d.value_mps2:.3g}  "
            f"# m/s2, model {d.model_mps2:g}\n" for d in kept)


def _rms(res: list[RunResiduals], runs: set[str]) -> float:
    """RMS of the lag across transfers of every fish alone on a belt in ``runs`` (not on the infeed, where the
    lag is the drop's): what the knobs are fitted on.
    (Not the tracks of bulk batches, nor pairs parting: with five bulk runs they move by chance with any
    change of a parameter, since a pile is chaotic, and would decide a knob by that chance.)"""
    ss, n = 0.0, 0
    for r in res:
        if r.run_id in runs and not r.error:
            a, b = r.squares("transfers")
            ss, n = ss + a, n + b
    return float(np.sqrt(ss / n)) if n else float("nan")


def _track_rms(res: list[RunResiduals], runs: set[str]) -> float:
    v = [r.track_rms_m for r in res if r.run_id in runs and not r.error and np.isfinite(r.track_rms_m)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")


def measured_rows(dataset: Dataset) -> list[RunResiduals]:
    """Each run's belt rows from its measured tracks alone (no simulation: every error zero): which fish rode
    alone on which belt."""
    out = []
    for run in dataset.runs:
        rows = belt_residuals(run, track_errors(run.tracks, run.tracks), dataset.line)
        out.append(RunResiduals(run.id, rows, typed_frame([], PAIR_RESIDUAL_DTYPES), 0.0))
    return out


def choose_fit_runs(baseline: list[RunResiduals]) -> tuple[list[str], list[str]]:
    """(fit runs, held-out runs): the runs with the most fish alone on a belt, at least half of them; with
    three runs or more at least one is held out."""
    counts = {b.run_id: len(alone(b.rows)) for b in baseline if not b.error}
    order = sorted(counts, key=lambda r: (-counts[r], r))
    n_fit = max(1, int(np.ceil(len(order) / 2)))
    if len(order) >= 3:
        n_fit = min(n_fit, len(order) - 1)
    fit = sorted(order[:n_fit])
    return fit, sorted(set(order) - set(fit))


def calibrate(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
              progress: Callable[[str], None] | None = None) -> Calibration:
    """Calibrate the base model on ``dataset`` (see the module docstring)."""
    refuse_unreplayed(dataset, "calibrate")  # devices it cannot fire: not a fit of the line
    with pool_for(workers) as pool:  # one pool for every re-simulation: a new process pays for importing Exudyn
        return calibrate_with_pool(dataset, base or measured_data_plant(), pool, seed, progress or (lambda text: None))


def _constant_fits(resp: Responses, base: PlantParams, rng: np.random.Generator) -> list[KnobFit]:
    """The friction level (and joint stiffening, when rigor was simulated) as knobs: the ``constant`` model of the
    level responses, with its held-out gain against leaving every level off (one gain for both).  A constant whose
    best value is not physically plausible (:data:`PLAUSIBLE`) is held at the model's value and the others refitted
    without it: it is reported as a finding, and the base the causes are judged against does not carry it."""
    resp = resp.only(MODELS["constant"].kinds)  # the rows a constant level changes: not the drops (less their mean)
    names = ["friction_level"] + (["joint_stiffening"] if "rigor" in resp.values else [])
    m = fit_model(MODELS["constant"], resp, rng)
    implausible: dict[str, list[str]] = {}
    for name in names:
        trial = base.model_copy(deep=True)
        KNOBS[name].apply(trial, m.values[name])
        if found := _implausible(trial, KNOBS[name].writes):
            implausible[name] = found
    best = dict(m.values)
    if implausible:
        m = fit_model(MODELS["constant"], resp, rng, fixed={n: KNOBS[n].off for n in implausible})
    off = resp.run_ss({})
    gain, ci = gain_with_ci(off - m.cv_ss, off, rng)
    n = max(int(resp.counts.sum()), 1)
    fits = []
    for name in names:
        v = m.values[name]
        f = KnobFit(name, v, best[name], m.ci95[name] if name not in implausible else (best[name], best[name]), gain,
                    ci, kept=bool(ci[0] > 0.0) and name not in implausible, implausible=implausible.get(name, []))
        at = {"friction": np.full(len(resp.runs), m.values["friction_level"]),
              "rigor": np.full(len(resp.runs), m.values.get("joint_stiffening", 0.0))}
        f.errors = {KNOBS[name].off: float(resp.lag_ss({}).sum() / n), v: float(resp.lag_ss(at).sum() / n)}
        fits.append(f)
    return fits


def calibrate_with_pool(dataset: Dataset, base: PlantParams, pool, seed: int, say: Callable[[str], None],
                        levels: tuple[Level, ...] = (FRICTION,), fit_base: bool = True,
                        heldout_before: bool = True) -> Calibration:
    """:func:`calibrate` with the re-simulations on ``pool``.  ``levels``: the level responses to simulate on the
    fit runs (``diagnose`` adds rigor, whose model is fitted on them); ``fit_base`` False: measure the responses
    but change nothing (a dataset this simulator made).  ``heldout_before`` False: the held-out runs are not
    re-simulated with the model as given, only with the calibrated one (their error before is then unknown)."""
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    runs = dataset.runs
    fit_ids, heldout_ids = choose_fit_runs(measured_rows(dataset))
    fit_runs = [r for r in runs if r.id in fit_ids]
    say(f"fitting on {len(fit_ids)} runs with the most fish alone ({', '.join(fit_ids)}); held out: "
        + (", ".join(heldout_ids) or "none"))
    first = runs if heldout_before or not fit_base else fit_runs
    say(f"baseline: re-simulating {len(first)} runs with the model as given")
    sims = resimulate_many(dataset.line, first, [base] * len(first), pool=pool, workers=1, residuals=True)
    failed = {r.run_id: r.error for r in sims if r.error}
    if len(failed) == len(sims) or not set(fit_ids) - set(failed):
        rid = next(iter(failed))
        raise SimulationError(f"run '{rid}': {failed[rid]} (re-simulating it with the model as it is, before "
                              "calibrating; no run to fit on is left)")
    for rid, error in failed.items():  # a pile the model cannot simulate must not take the other runs with it
        say(f"run {rid} could not be re-simulated with the model as given ({error}); it is left out")
    heldout_ids = sorted(set(heldout_ids) | (set(fit_ids) & set(failed)))  # tried again with the calibrated model
    fit_ids = [r for r in fit_ids if r not in failed]
    fit_runs = [r for r in fit_runs if r.id not in failed]
    sim_of = {r.id: s for r, s in zip(first, sims)}
    simulated_base = {b.run_id: b for b in residuals_of(dataset.subset(first), sims)}
    baseline = [simulated_base.get(r.id) or RunResiduals(r.id, typed_frame([], BELT_RESIDUAL_DTYPES),
                                                         typed_frame([], PAIR_RESIDUAL_DTYPES), float("nan"),
                                                         "not re-simulated with the model as given")
                for r in runs]
    base_by_run = {b.run_id: b for b in baseline}
    timing["baseline"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    # a stream of its own, so that the knobs' bootstraps draw the same whether or not drives are fitted
    drives = fit_drive_responses(dataset, fit_ids, np.random.default_rng([seed, 1])) if fit_base else []
    timing["drives"] = time.perf_counter() - t1

    t1 = time.perf_counter()
    params = base.model_copy(deep=True)
    fit_base_res = {r: base_by_run[r] for r in fit_ids}
    resp = _level_responses(dataset, fit_runs, base, fit_base_res, levels, pool, say)
    timing["levels"] = time.perf_counter() - t1
    fits = _constant_fits(resp, base, rng) if fit_base else []
    for f in fits:
        if f.kept:
            KNOBS[f.name].apply(params, f.value)

    # the held-out runs with the calibrated model
    t1 = time.perf_counter()
    held_runs = [r for r in runs if r.id in set(heldout_ids)]
    resim_held = [r for r in held_runs if params != base or r.id not in sim_of]
    held_after = {r: base_by_run[r] for r in heldout_ids}
    if resim_held:
        say(f"held-out runs: re-simulating {len(resim_held)} with the calibrated model")
        held_sims = resimulate_many(dataset.line, resim_held, [params] * len(resim_held), pool=pool, workers=1,
                                    residuals=True)
        held_after.update({r.run_id: r for r in residuals_of(dataset.subset(resim_held), held_sims)})
        sim_of.update({r.id: s for r, s in zip(resim_held, held_sims)})
    timing["heldout"] = time.perf_counter() - t1
    after = [fit_base_res.get(b.run_id) or held_after[b.run_id] for b in baseline]
    timing["total"] = time.perf_counter() - t0
    groups = {"fit": set(fit_ids), "heldout": set(heldout_ids), "all": set(fit_ids) | set(heldout_ids)}
    rms_after = {g: _rms(after, ids) for g, ids in groups.items()}
    kept = {f.name: f.value for f in fits if f.kept}
    if kept:  # the fit runs at the fitted levels: interpolated in the responses
        n = max(int(resp.counts.sum()), 1)
        levels_fit = {"friction": np.full(len(resp.runs), kept.get("friction_level", 1.0))}
        if "joint_stiffening" in kept:
            levels_fit["rigor"] = np.full(len(resp.runs), kept["joint_stiffening"])
        ss_fit = float(resp.lag_ss(levels_fit).sum())
        rms_after["fit"] = float(np.sqrt(ss_fit / n))
        held = [r for r in after if r.run_id in groups["heldout"] and not r.error]
        ss_h, n_h = sum(r.squares("transfers")[0] for r in held), sum(r.squares("transfers")[1] for r in held)
        rms_after["all"] = float(np.sqrt((ss_fit + ss_h) / max(n + n_h, 1)))
    return Calibration(base, params, fits, fit_ids, heldout_ids,
                       {g: _rms(baseline, ids) for g, ids in groups.items()}, rms_after,
                       {g: _track_rms(baseline, ids) for g, ids in groups.items()},
                       {g: _track_rms(after, ids) for g, ids in groups.items()}, timing, baseline, after,
                       resp, base.model_copy(deep=True), [sim_of[r.id] for r in runs], drives)


def _level_responses(dataset: Dataset, fit_runs: list[Run], base: PlantParams, base_res: dict[str, RunResiduals],
                     levels: tuple[Level, ...], pool, say: Callable[[str], None]) -> Responses:
    """The fit runs simulated at each level's grid, then up to twice beyond an end for the runs whose own best
    level lies there (:func:`fishfmu.analysis.levels.responses`)."""
    hours = {r.id: (r.hours_post_mortem if r.hours_post_mortem is not None else DEFAULT_HOURS_POST_MORTEM)
             for r in fit_runs}
    simulated: dict[tuple[str, float], dict[str, RunResiduals]] = {}
    pending = [(lv, v, fit_runs) for lv in levels for v in lv.grid]
    resp = responses(base_res, simulated, hours)
    for _ in range(3):
        jobs = [(lv, v, r) for lv, v, on in pending for r in on]
        say("levels: " + "; ".join(f"{lv.name} {v:g} on " + (f"{len(on)} runs" if len(on) > 1 else on[0].id)
                                   for lv, v, on in pending))
        level_sims = resimulate_many(dataset.line, [r for _, _, r in jobs],
                                     [lv.params(base, v, hours[r.id]) for lv, v, r in jobs], pool=pool, workers=1,
                                     residuals=True)
        for (lv, v, r), s in zip(jobs, level_sims):
            simulated.setdefault((lv.name, v), {})[r.id] = residuals_of(dataset.subset([r]), [s])[0]
        resp = responses(base_res, simulated, hours)
        own = run_levels(resp)
        pending = []
        for lv in levels:
            values = list(resp.values[lv.name])
            best = own[f"{lv.name}_level"].to_numpy(float)
            for low, end in ((True, values[0]), (False, values[-1])):
                at_end = [r for r in fit_runs if np.isclose(best[resp.runs.index(r.id)], end, rtol=1e-6)]
                nxt = lv.beyond(values, low) if at_end else None
                if nxt is not None:  # the others are held at the end (see levels.responses): far from their best
                    pending.append((lv, nxt, at_end))
        if not pending:
            break
    return resp


def _implausible(p: PlantParams, paths: tuple[str, ...]) -> list[str]:
    """Each of ``paths`` whose value in ``p`` lies outside :data:`PLAUSIBLE`, as a sentence a user can act on."""
    out = []
    for path in paths:
        if path in PLAUSIBLE:
            lo, hi, why = PLAUSIBLE[path]
            v = plant_value(p, path)
            if not lo <= v <= hi:
                out.append(f"{path} would be calibrated to {v:.3g}, outside the plausible {lo:g}-{hi:g} ({why}): it "
                           "fits these runs best, but more likely stands for something the model lacks; held at the "
                           "model's value, the other constants fitted without it")
    return out


def findings(c: Calibration) -> list[str]:
    """The calibrated values that were not applied because they are not physically plausible."""
    return [text for f in c.fits for text in f.implausible]
