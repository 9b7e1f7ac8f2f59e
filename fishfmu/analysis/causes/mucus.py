"""Mucus: fish-belt friction follows hours post mortem as the slaughter mucus dries.

Signature: the slip of fish dropped alone onto the infeed (the time they lose to the belt beyond their fall) against
the batch's age; with one friction coefficient a fish wholly on one belt slides ``v / (2 mu g)`` whatever its age.
Drying raises friction, so the slip falls (sign -1).  Extension: friction x level x (1 + gain (1 - exp(-h / tau))),
fresh fish at the level (against the calibrated friction, fitted on every age at once), fitted by dropping every drop
alone again in the extended plant (:func:`fit`).
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test, log_hours_shapes, robust
from fishfmu.analysis.extension_fit import CandidateFit, FitContext
from fishfmu.analysis.fitting import folds, heldout_score
from fishfmu.analysis.observations import drop_rows
from fishfmu.analysis.resim import resimulate_drops


def apply(p: PlantParams, gain: float, time_constant_h: float | None = None, friction_level: float | None = None) -> None:
    """Friction x ``friction_level`` (fresh fish on the belt, against the calibrated model's) x (1 + ``gain``
    (1 - exp(-h / ``time_constant_h``))) at h hours post mortem."""
    p.extensions.mucus_friction.gain = gain
    if time_constant_h is not None:
        p.extensions.mucus_friction.time_constant_h = time_constant_h
    if friction_level is not None:
        p.friction.fish_belt *= friction_level


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    """Strength 1: the mucus dries and friction doubles from fresh to dry."""
    p.extensions.mucus_friction.gain = 1.0 * s


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """Fish-belt friction follows hours post mortem; seen in the slip of drops alone (the belt's speed a nuisance
    term)."""
    ok = rows["drops"].dropna(subset=["hours_post_mortem"])
    shapes, names = log_hours_shapes(ok["hours_post_mortem"].to_numpy(float))
    d = Design(robust(ok["slip_s"].to_numpy(float)), ok["run_id"].to_numpy(), shapes, names,
               ok[["belt_speed_mps"]].to_numpy(float), within=False, sign=-1)
    return covariate_test("mucus_friction", "slip of fish dropped alone [s]", "hours post mortem", d, "rows", rng)


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """Fish-belt friction at 1 h and at 48 h post mortem (the model's fish-belt friction x the fitted level x the
    drying factor), and how much it rises between them (x)."""
    level = values.get("friction_level", 1.0) * ctx.base.friction.fish_belt
    gain, tau = values.get("gain", 0.0), values.get("time_constant_h", 24.0)
    at = {h: level * (1.0 + gain * (1.0 - np.exp(-h / tau))) for h in (1.0, 48.0)}
    return {"friction_1h": float(at[1.0]), "friction_48h": float(at[48.0]), "rise_1h_to_48h": float(at[48.0] / at[1.0])}


LEVELS_X = (0.25, 0.35, 0.5, 0.7, 1.0, 1.5, 2.5)
"""Fish-belt friction over the calibrated model's at which every drop alone is dropped again.  For a drop alone the
extension changes nothing but that fish's friction, so the extended plant's drop at any shape is the plant's drop at
the friction the shape gives the fish's age: these levels span every shape searched."""
FRESH_X = tuple(float(x) for x in np.round(np.geomspace(LEVELS_X[0], 1.0, 11), 3))
"""Fish-belt friction at 1 h over the calibrated model's, searched: from slime that quarters it (0.11 on the model's
0.45) to none.  The calibrated friction is fitted on every age at once; where fresh fish slide more, it is too high
for them."""
DRY_X = tuple(float(x) for x in np.round(np.geomspace(1.0, LEVELS_X[-1], 7), 3))
"""Fish-belt friction at 48 h over the calibrated model's, searched up to the highest level simulated (a damp hall
to slime washed off a fish that then dries)."""
TIME_CONSTANTS_H = (3.0, 6.0, 12.0, 24.0, 48.0, 96.0)
"""How fast the mucus dries: within hours in a dry hall, over days on ice."""
MOST_GAIN = 8.0
"""The largest gain searched: friction x9 once dry."""


def shape_values(fresh_x: float, dry_x: float, time_constant_h: float) -> tuple[float, float, float] | None:
    """(gain, time constant, friction level) whose friction is ``fresh_x`` at 1 h and ``dry_x`` at 48 h (over the
    calibrated); None where the plant's shape cannot reach that rise at that drying time within its bounds."""
    a1, a48 = (1.0 - np.exp(-h / time_constant_h) for h in (1.0, 48.0))
    rise = dry_x / fresh_x
    if rise < 1.0 or a48 - rise * a1 <= 0.0:
        return None
    gain = (rise - 1.0) / (a48 - rise * a1)
    if gain > MOST_GAIN:
        return None
    return gain, time_constant_h, fresh_x / (1.0 + gain * a1)


def friction_x(values: tuple[float, float, float], hours: np.ndarray) -> np.ndarray:
    """The extension's friction over the calibrated at ``hours`` post mortem, for (gain, time constant, level)."""
    gain, tau, level = values
    return level * (1.0 + gain * (1.0 - np.exp(-np.asarray(hours, dtype=float) / tau)))


def fit(cand: Candidate, ctx: FitContext) -> CandidateFit:
    """Fitted on what its test reads: every drop alone of the dataset dropped again, alone, in the plant
    (:func:`fishfmu.analysis.resim.resimulate_drops`, a few per cent of a run's cost) at each friction of
    :data:`LEVELS_X`, its slip against the measured one.  A drop of our model lands chaotically (its slip scatters
    about 16 ms beyond what its heading explains, the measured ones 10 ms), with a new scatter at every friction; the
    slip's answer to friction is therefore taken pooled over the drops (their mean change from the calibrated
    friction, each scaled by its belt's speed, linear in 1 / friction between the levels and flat beyond them), and
    each drop's extended slip is its own slip at the calibrated friction plus that answer at the friction the shape
    gives its age.  Our model's drops depend on the fish's heading where the measured ones do not (the creep of
    ``docs/diagnosis.md``, *What our model gets wrong*): a nuisance term of the error, fitted with it.  No constant
    is: a slip goes as 1 / friction, so with a free constant only the difference of 1 / friction between ages is
    decided.  Every shape of friction at 1 h (:data:`FRESH_X`), at 48 h (:data:`DRY_X`) and drying time
    (:data:`TIME_CONSTANTS_H`) is scored; each held-out run with the shape and nuisance chosen on the other runs; a
    value at an end of those searched is said to be there."""
    cal = ctx.cal
    ok = {b.run_id for b in cal.after if not b.error}
    drops = drop_rows(ctx.dataset)
    drops = drops[drops["run_id"].isin(ok)].reset_index(drop=True)
    runs = {r.id: r for r in ctx.dataset.runs if r.id in set(drops["run_id"])}
    if len(runs) < 2:
        return CandidateFit(cand.name, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="s")
    ids = sorted(runs)
    run_of = drops["run_id"].to_numpy()
    ctx.say(f"fit {cand.name}: {len(drops)} drops alone of {len(runs)} runs dropped again at friction "
            f"x{', x'.join(f'{x:g}' for x in LEVELS_X)}")
    jobs = [(runs[r], list(drops["fish_id"][run_of == r]), cand.params(cal.params, 0.0, None, x))
            for x in LEVELS_X for r in ids]
    out = resimulate_drops(ctx.dataset.line, jobs, pool=ctx.pool)
    slips = np.full((len(LEVELS_X), len(drops)), np.nan)
    for n in range(len(LEVELS_X)):
        sim = {(r, f): v for r, d in zip(ids, out[n * len(ids):(n + 1) * len(ids)]) for f, v in d.items()}
        slips[n] = [sim[(r, f)] for r, f in zip(run_of, drops["fish_id"])]
    base = slips[LEVELS_X.index(1.0)]
    failed = ~np.isfinite(base)  # drops the calibrated model cannot read are left out
    speed = drops["belt_speed_mps"].to_numpy(float)
    scale = speed / float(np.mean(speed))
    answer = np.array([np.nanmean(((slips[n] - base) / scale)[~failed]) for n in range(len(LEVELS_X))])
    answer = np.nan_to_num(answer)  # a level at which no drop could be read: as the calibrated friction
    inverse = 1.0 / np.array(LEVELS_X)
    order = np.argsort(inverse)

    shapes = [(1.0, 1.0, 24.0)] + [sh for sh in itertools.product(FRESH_X, DRY_X, TIME_CONSTANTS_H)
                                   if sh[:2] != (1.0, 1.0) and shape_values(*sh) is not None]
    hours = drops["hours_post_mortem"].to_numpy(float)
    measured = drops["slip_s"].to_numpy(float)
    # each shape's residual per drop: simulated (calibrated, plus the pooled answer at its friction) - measured
    res = np.array([np.where(failed, 0.0, base - measured + scale * np.interp(
        1.0 / (friction_x(_values_tuple(sh), hours)), inverse[order], answer[order])) for sh in shapes])
    heading = drops["heading"].to_numpy(float)
    by_run = np.array([(run_of == r) & ~failed for r in ids], dtype=float)

    def without_creep(train: np.ndarray) -> np.ndarray:
        """(shape, drop): each shape's residuals less its heading term fitted on the ``train`` drops."""
        w = (train & ~failed).astype(float)
        b = (res * heading * w).sum(axis=1) / max(float((heading**2 * w).sum()), 1e-12)
        return res - b[:, None] * heading

    def errors(train: np.ndarray) -> np.ndarray:
        """(shape, run): squared error of the run's drops once each shape's heading term is taken out."""
        return without_creep(train) ** 2 @ by_run.T

    u, e0 = np.zeros(len(ids)), np.zeros(len(ids))
    side = []
    for fold in folds(ids):
        test = np.array([r in fold for r in ids])
        r_adj = without_creep(~np.isin(run_of, fold))
        e = r_adj**2 @ by_run.T
        chosen = int(np.argmin(e[:, ~test].sum(axis=1)))  # the base first: a tie keeps it
        u[test], e0[test] = e[0, test] - e[chosen, test], e[0, test]
        for r in fold:  # the run's drops as measured, and as each model has them once its heading creep is out
            m = (run_of == r) & ~failed
            side.append({"run_id": r, "covariate": float(np.median(hours[m])), "measured": float(measured[m].mean()),
                         "base": float((measured + r_adj[0])[m].mean()),
                         "extended": float((measured + r_adj[chosen])[m].mean())})
    fit_out = CandidateFit(cand.name, error_unit="s").score(heldout_score(ids, u, e0, int((~failed).sum()), ctx.rng))
    fit_out.side_by_side = pd.DataFrame(side).sort_values("covariate", kind="stable").reset_index(drop=True)
    fit_out.side_by_side.attrs.update(covariate="hours post mortem", quantity="mean slip of the run's drops alone [s]")
    table = errors(np.ones(len(drops), dtype=bool))
    chosen = shapes[int(np.argmin(table.sum(axis=1)))]
    fit_out.values = _values(chosen)
    boot = [_values(shapes[int(np.argmin(table @ np.bincount(ctx.rng.integers(0, len(ids), len(ids)),
                                                            minlength=len(ids))))]) for _ in range(300)]
    for name in cand.parameters:
        fit_out.ci95[name] = tuple(float(np.percentile([b[name] for b in boot], q)) for q in (2.5, 97.5))
    ends = {"friction_level": (chosen[0], FRESH_X, "friction at 1 h"), "gain": (chosen[1], DRY_X, "friction at 48 h")}
    if chosen[:2] != (1.0, 1.0):
        ends["time_constant_h"] = (chosen[2], TIME_CONSTANTS_H, "drying time")
    for name, (x, grid, what) in ends.items():
        if x == grid[0] and x != 1.0 or x == grid[-1] and x != 1.0:
            fit_out.at_grid_end[name] = (f"{'lowest' if x == grid[0] else 'highest'} value searched ({what} "
                                         f"{x:g}{' h' if name == 'time_constant_h' else ' x the calibrated'})")
    ctx.say(f"fit {cand.name}: the drops' mean slip change at friction x{', x'.join(f'{x:g}' for x in LEVELS_X)}: "
            + ", ".join(f"{1e3 * a:+.1f} ms" for a in answer))
    return fit_out


def _values_tuple(sh: tuple[float, float, float]) -> tuple[float, float, float]:
    """A searched shape (friction at 1 h, at 48 h, drying time) as (gain, time constant, level)."""
    return (0.0, sh[2], 1.0) if sh[:2] == (1.0, 1.0) else shape_values(*sh)


def _values(sh: tuple[float, float, float]) -> dict[str, float]:
    gain, tau, level = _values_tuple(sh)
    return {"gain": float(gain), "time_constant_h": float(tau), "friction_level": float(level)}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: the slip of drops alone against hours post mortem."""
    drops = rows.get("drops")
    if drops is not None and len(drops):
        ax.plot(drops["hours_post_mortem"], 1e3 * drops["slip_s"], ".", alpha=0.5)
    ax.set(xscale="log", xlabel="hours post mortem", ylabel="slip of a drop alone [ms]")


CANDIDATE = Candidate(
    "mucus_friction", "belt friction of fresh fish (level), its change once the mucus has dried (gain), and how "
    "fast it dries",
    ("gain", "time_constant_h", "friction_level"), "", 0.0, (), (0.0, MOST_GAIN), "plant", apply,
    ("extensions.mucus_friction.gain", "extensions.mucus_friction.time_constant_h", "friction.fish_belt"),
    test=test,
    decides="more runs of fish dropped one at a time onto the infeed, at more ages post mortem (fresh batches, under "
            "8 h, most of all)",
    fit=fit, groups=("drops", "drops", "drops"), synthetic=hide, terms=terms,
    primary="rise_1h_to_48h",
    explains=(("drops", "hours_post_mortem"), ("transfers", "hours_post_mortem")), plot=plot)
