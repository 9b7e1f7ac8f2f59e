"""``fishfmu calibrate``: fit the parameters every line has and nobody knows exactly, before any
effect is judged.

A measured line differs from its model in ways no hidden effect explains: real friction between
fish and a belt is not the table's 0.45, and it is not the same along a salmon (head, belly, tail
and fin differ in skin, scales and mucus).  On data from an independent simulator of the pilot line
with no effect hidden at all, the default model puts fish that ride head first 8-19 cm ahead of the
data at every transfer while tail-first ones match: a base mismatch larger than most effects.
Judged against that model, every effect drowns in it.

So the base model is calibrated first, on the fish the data shows alone on a belt (their lag across
a transfer is what friction decides):

1. **Baseline.** Every run re-simulated with the model as given; residuals per fish and belt.
2. **Fit runs.** The runs with the most fish riding alone (at least half of the runs; chosen from the
   residual tables, not from names or notes).  The others are held out: the calibration never sees
   them, and the error on them before and after is the check that it generalises.
3. **Knobs** (:data:`KNOBS`), fitted one stage after the other on the fit runs, each at a few values
   simulated around the model's and the minimum of its error curve taken between them: first the
   gradient of fish-belt friction along the fish (which end grips more decides how a fish is taken
   over by a faster belt: head first or tail first), then the fish-belt friction coefficient given
   it.  Each value gets a 95 % interval from a bootstrap over the fit runs and a held-out gain from
   folds of them.
4. **Check.** A stage's values are kept only if, with them, every run re-simulated, the fish alone in
   the held-out runs lag no worse across the transfers than before the stage: a knob fitted on the
   runs with most fish alone must carry over to the fish alone in the other runs (bulk batches).
   If they are worse, half the change is tried once; if that is worse too, the stage is dropped.  A knob whose held-out gain
   interval (folds of the fit runs) does not exclude zero is not tried at all.  The error before and
   after is reported for the fit runs and the held-out runs.

The result is a scenario fragment (``calibrated.toml``, only ``[plant]`` tables) that ``fishfmu
compare`` and ``diagnose`` take with ``--scenario`` (and whose tables a scenario for ``run`` can take).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from plant.errors import SimulationError
from plant.measured import Dataset
from plant.params import PlantParams

from fishfmu.analysis.candidates import plant_tables, plant_value
from fishfmu.analysis.fitting import RunResiduals, folds, gain_with_ci, residuals_of, vertex
from fishfmu.analysis.residuals import alone
from fishfmu.analysis.resim import pool_for, resimulate_many


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
    stage: int
    """Knobs of one stage are fitted together (independent residuals), stages one after the other."""


def _belt(p: PlantParams, m: float) -> None:
    p.friction.fish_belt = float(p.friction.fish_belt * m)


def _gradient(p: PlantParams, g: float) -> None:
    p.friction.belt_gradient = float(np.clip(p.friction.belt_gradient + g, -0.8, 0.8))


KNOBS: dict[str, Knob] = {k.name: k for k in (
    Knob("belt_gradient", "fish-belt friction from head to fin: head x(1 - g), fin x(1 + g) (added to the model's g)",
         0.0, (0.3, 0.5, 0.7), (-0.8, 0.8), "transfers", _gradient, ("friction.belt_gradient",), 1),
    Knob("belt_friction", "fish-belt friction coefficient (multiplier)", 1.0, (0.8, 1.25), (0.3, 3.0), "transfers",
         _belt, ("friction.fish_belt",), 2),
)}
"""The knobs, in stages.  Friction by slip direction (``direction_friction``) also makes head-first and
tail-first fish differ, but it stays a candidate effect: on the independent simulator's data without an
effect it removed the asymmetry of fish alone as well as a gradient along the fish (slipping tail first
x0.25: lag RMS 9.2 -> 3.8 cm on the sparse runs) but made the bulk batches worse (track RMS 19.0 -> 21.6 cm),
where the gradient (0.6) made them better (see README)."""


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
    track_rms_before_m: dict[str, float]
    track_rms_after_m: dict[str, float]
    timing_s: dict[str, float]
    baseline: list[RunResiduals]
    after: list[RunResiduals]
    sims_after: list = field(default_factory=list, repr=False)
    """The calibrated model's re-simulation of every run (:class:`~fishfmu.analysis.resim.Resim`): the
    baseline of a diagnosis that follows."""

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
            return head + "# nothing changed: no base parameter fitted the data clearly better than the model's\n"
        return head + plant_tables({path: value for path, (_, value) in changed.items()})


def _squares(res: dict[str, RunResiduals], runs: list[str], group: str | None) -> tuple[np.ndarray, np.ndarray]:
    sq = [res[r].squares(group) for r in runs]
    return np.array([a for a, _ in sq]), np.array([n for _, n in sq], dtype=float)


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


def fit_knob(knob: Knob, runs: list[str], table: dict[float, dict[str, RunResiduals]],
             rng: np.random.Generator) -> KnobFit:
    """The change with the least error of the knob's residuals on ``runs`` (``table``: residuals per
    simulated change, ``knob.off`` the model's), its bootstrap interval and its held-out gain over folds of runs."""
    values = np.array(sorted(table))
    ss, nn = zip(*(_squares(table[v], runs, knob.group) for v in values))
    ss, nn = np.array(ss), np.array(nn)
    fit = KnobFit(knob.name, knob.off)
    if nn.sum() == 0:
        return fit
    err = ss.sum(axis=1) / np.maximum(nn.sum(axis=1), 1)
    fit.errors = {float(v): float(e) for v, e in zip(values, err)}
    fit.value = fit.fitted = vertex(values, err)
    boot = []
    for _ in range(300):
        i = rng.integers(0, len(runs), len(runs))
        boot.append(vertex(values, ss[:, i].sum(axis=1) / np.maximum(nn[:, i].sum(axis=1), 1)))
    fit.ci95 = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    one = int(np.flatnonzero(values == knob.off)[0])
    u, e0 = np.zeros(len(runs)), ss[one].copy()
    for fold in folds(runs):
        test = np.array([r in fold for r in runs])
        best = int(np.argmin(ss[:, ~test].sum(axis=1) / np.maximum(nn[:, ~test].sum(axis=1), 1)))
        u[test] = ss[one, test] - ss[best, test]
    fit.heldout_gain, fit.heldout_gain_ci95 = gain_with_ci(u, e0, rng)
    fit.kept = bool(fit.heldout_gain_ci95[0] > 0.0)
    return fit


def calibrate(dataset: Dataset, base: PlantParams | None = None, workers: int | None = None, seed: int = 0,
              progress: Callable[[str], None] | None = None) -> Calibration:
    """Calibrate the base model on ``dataset`` (see the module docstring)."""
    with pool_for(workers) as pool:  # one pool for every re-simulation: a new process pays for importing Exudyn
        return calibrate_with_pool(dataset, base or PlantParams(), pool, seed, progress or (lambda text: None))


def calibrate_with_pool(dataset: Dataset, base: PlantParams, pool, seed: int, say: Callable[[str], None]) -> Calibration:
    """:func:`calibrate` with the re-simulations on ``pool`` (``fishfmu diagnose`` calibrates on its own pool)."""
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    runs = dataset.runs
    say(f"baseline: re-simulating {len(runs)} runs")
    sims = resimulate_many(dataset.line, runs, [base] * len(runs), pool=pool, workers=1)
    failed = [(r.run_id, r.error) for r in sims if r.error]
    if failed:
        raise SimulationError(f"run '{failed[0][0]}': {failed[0][1]} (re-simulating it with the model as it is, "
                              "before calibrating)")
    baseline = residuals_of(dataset, sims)
    timing["baseline"] = time.perf_counter() - t0
    fit_ids, heldout_ids = choose_fit_runs(baseline)
    fit_runs = [r for r in runs if r.id in fit_ids]
    sub = Dataset(dataset.name, dataset.description, dataset.line, dataset.kpi, fit_runs)
    base_by_run = {b.run_id: b for b in baseline}
    say(f"fitting on {len(fit_ids)} runs with the most fish alone ({', '.join(fit_ids)}); held out: "
        + (", ".join(heldout_ids) or "none"))

    params = base.model_copy(deep=True)
    fits: list[KnobFit] = []
    stage_base = base_by_run  # residuals of the model as fitted so far (``off`` of the next stage's knobs)
    current, current_sims = baseline, sims  # every run with the model as fitted so far
    for stage in sorted({k.stage for k in KNOBS.values()}):
        t1 = time.perf_counter()
        knobs = [k for k in KNOBS.values() if k.stage == stage]
        jobs = [(k, m) for k in knobs for m in k.grid]
        say(f"stage {stage}: " + "; ".join(f"{k.name} {'x' if k.off == 1.0 else '+'} {', '.join(f'{m:g}' for m in k.grid)}"
                                           for k in knobs))
        variants = []
        for k, m in jobs:
            p = params.model_copy(deep=True)
            k.apply(p, m)
            variants.append(p)
        sims = resimulate_many(dataset.line, fit_runs * len(jobs), [p for p in variants for _ in fit_runs],
                               pool=pool, workers=1)
        kept = []
        for k in knobs:
            table = {k.off: {r: stage_base[r] for r in fit_ids}}
            for j, (kk, m) in enumerate(jobs):
                if kk is k:
                    res = residuals_of(sub, sims[j * len(fit_runs):(j + 1) * len(fit_runs)])
                    # a failed simulation counts as no better than the model's
                    table[m] = {r.run_id: (stage_base[r.run_id] if r.error else r) for r in res}
            f = fit_knob(k, fit_ids, table, rng)
            fits.append(f)
            if f.kept:
                kept.append(f)
        if kept:
            # the stage's values on every run: kept only if the held-out runs' tracks do not get worse (the
            # check that what was fitted on fish alone carries over to the other runs, e.g. bulk batches);
            # if they do, half the change is tried once (fish alone and piles may want different amounts)
            held = set(heldout_ids)
            for share in (1.0, 0.5):
                trial_params = params.model_copy(deep=True)
                for f in kept:
                    f.value = KNOBS[f.name].off + share * (f.value - KNOBS[f.name].off)
                    KNOBS[f.name].apply(trial_params, float(np.clip(f.value, *KNOBS[f.name].bounds)))
                say(f"stage {stage}: checking " + ", ".join(f"{f.name} {f.value:.3g}" for f in kept) + " on every run")
                sims = resimulate_many(dataset.line, runs, [trial_params] * len(runs), pool=pool, workers=1)
                trial = residuals_of(dataset, sims)
                worse = any(r.error for r in trial) or (bool(held) and _rms(trial, held) > _rms(current, held))
                if held and not any(r.error for r in trial):
                    say(f"  held-out runs: lag RMS {_rms(current, held):.3f} -> {_rms(trial, held):.3f} m"
                        + (": worse" if worse else ""))
                if not worse:
                    params, current, current_sims = trial_params, trial, sims
                    by_run = {r.run_id: r for r in trial}
                    stage_base = {r: by_run[r] for r in fit_ids}
                    break
            else:
                for f in kept:
                    f.kept, f.rejected_on_heldout = False, True
        timing[f"stage_{stage}"] = time.perf_counter() - t1

    after = current
    timing["total"] = time.perf_counter() - t0
    groups = {"fit": set(fit_ids), "heldout": set(heldout_ids), "all": set(fit_ids) | set(heldout_ids)}
    return Calibration(base, params, fits, fit_ids, heldout_ids,
                       {g: _rms(baseline, ids) for g, ids in groups.items()},
                       {g: _rms(after, ids) for g, ids in groups.items()},
                       {g: _track_rms(baseline, ids) for g, ids in groups.items()},
                       {g: _track_rms(after, ids) for g, ids in groups.items()}, timing, baseline, after,
                       current_sims)


def calibration_document(c: Calibration, base: PlantParams) -> dict:
    """calibration.json: what was fitted, on which runs, and the errors before and after."""
    return {
        "fit_runs": c.fit_runs, "heldout_runs": c.heldout_runs,
        "knobs": [{"name": f.name, "description": KNOBS[f.name].description, "value": f.value,
                   "fitted": f.fitted, "fitted_ci95": list(f.ci95), "heldout_gain": f.heldout_gain,
                   "heldout_gain_ci95": list(f.heldout_gain_ci95), "kept": f.kept,
                   "rejected_on_heldout_runs": f.rejected_on_heldout,
                   "error_m2_per_value": {f"{k:g}": v for k, v in f.errors.items()}} for f in c.fits],
        "changed": {path: {"model": a, "calibrated": b} for path, (a, b) in c.changed(base).items()},
        "lag_rms_m": {"before": c.rms_before_m, "after": c.rms_after_m},
        "track_rms_m": {"before": c.track_rms_before_m, "after": c.track_rms_after_m},
        "timing_s": c.timing_s,
    }


def write_calibration(c: Calibration, base: PlantParams, out) -> dict:
    """``calibrated.toml`` (the fragment) and ``calibration.json`` in the folder ``out``."""
    from pathlib import Path

    from fishfmu.output.atomic import json_safe, write_json_atomic, write_text_atomic
    out = Path(out)
    paths = {"fragment": out / "calibrated.toml", "json": out / "calibration.json"}
    write_text_atomic(paths["fragment"], c.fragment(base))
    write_json_atomic(paths["json"], json_safe(calibration_document(c, base)))
    return paths


def summary_lines(c: Calibration, base: PlantParams) -> list[str]:
    """What the calibration changed and what it gained, for the console."""
    lines = []
    for f in c.fits:
        gain = f"held-out gain {f.heldout_gain:.0%} [{f.heldout_gain_ci95[0]:.0%}, {f.heldout_gain_ci95[1]:.0%}]"
        kind = "x" if KNOBS[f.name].off == 1.0 else "+"
        applied = "" if f.value == f.fitted else f", applied {kind}{f.value:.3g}"
        lines.append(f"{f.name}: fitted {kind}{f.fitted:.3g} [{f.ci95[0]:.3g}, {f.ci95[1]:.3g}]{applied}, {gain}"
                     + ("" if f.kept else " (not kept: the held-out runs got worse)" if f.rejected_on_heldout
                        else " (not kept)"))
    for path, (a, b) in c.changed(base).items():
        lines.append(f"  {path}: {a:.4g} -> {b:.4g}")
    for g, label in (("fit", "fit runs"), ("heldout", "held-out runs")):
        if np.isfinite(c.rms_before_m[g]):
            lines.append(f"lag RMS on the {label}: {c.rms_before_m[g]:.3f} m -> {c.rms_after_m[g]:.3f} m; "
                         f"track RMS {c.track_rms_before_m[g]:.3f} m -> {c.track_rms_after_m[g]:.3f} m")
    lines.append(f"took {c.timing_s['total']:.0f} s")
    return lines
