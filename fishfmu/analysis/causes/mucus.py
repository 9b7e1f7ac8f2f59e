"""Mucus: fish-belt friction follows hours post mortem as the slaughter mucus dries.

Signature: the slip of fish dropped alone onto the infeed (the time they lose to the belt beyond their fall) against
the batch's age; with one friction coefficient a fish wholly on one belt slides ``v / (2 mu g)`` whatever its age.
Drying raises friction, so the slip falls (sign -1).  Extension: friction x level x (1 + gain (1 - exp(-h / tau))),
fresh fish at the level (against the calibrated friction, fitted on every age at once), fitted by dropping every drop
alone again in the extended plant (:func:`fit`).
"""

from __future__ import annotations

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


FRESH_X = (0.3, 0.4, 0.55, 0.75, 1.0)
"""Fish-belt friction at 1 h over the calibrated model's, searched: from slime that halves it and more (0.14 on the
model's 0.45) to none.  The calibrated friction is fitted on every age at once; where fresh fish slide more, it is
too high for them."""
DRY_X = (1.0, 1.5, 2.5, 4.0, 6.0)
"""Fish-belt friction at 48 h over the calibrated model's, searched: a damp hall to slime washed off a fish that then
dries."""
TIME_CONSTANTS_H = (6.0, 24.0, 96.0)
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


Shape = tuple[float, float, float]
"""(friction at 1 h, at 48 h, both over the calibrated model's; drying time [h]): a point of the search."""


def _neighbours(best: Shape) -> list[Shape]:
    """The shapes one step from ``best`` along each axis of the search (the drying time only where friction
    changes with age)."""
    i, j, k = FRESH_X.index(best[0]), DRY_X.index(best[1]), TIME_CONSTANTS_H.index(best[2])
    out = [(FRESH_X[a], best[1], best[2]) for a in (i - 1, i + 1) if 0 <= a < len(FRESH_X)]
    out += [(best[0], DRY_X[b], best[2]) for b in (j - 1, j + 1) if 0 <= b < len(DRY_X)]
    if best[:2] != (1.0, 1.0):
        out += [(best[0], best[1], TIME_CONSTANTS_H[c]) for c in (k - 1, k + 1) if 0 <= c < len(TIME_CONSTANTS_H)]
    return out


def fit(cand: Candidate, ctx: FitContext) -> CandidateFit:
    """Fitted on what its test reads: every drop alone of the dataset dropped again, alone, in the extended plant
    (:func:`fishfmu.analysis.resim.resimulate_drops`, a few per cent of a run's cost), its slip against the measured
    one.  Our model's drops depend on the fish's heading where the measured ones do not (the creep of
    ``docs/diagnosis.md``, *What our model gets wrong*): a nuisance term of the error, fitted with it.  No constant
    is: a slip goes as 1 / friction, so with a free constant only the difference of 1 / friction between ages is
    decided, and a fresh friction below the calibrated one would fit as well as a dry one above it.  The search walks a lattice of friction at 1 h
    (:data:`FRESH_X`), at 48 h (:data:`DRY_X`) and drying times (:data:`TIME_CONSTANTS_H`) from the calibrated model,
    a batch of neighbours at a time, while the error falls.  Each held-out run is scored with the shape and nuisance
    chosen on the other runs; a value at an end of the lattice is said to be there."""
    cal = ctx.cal
    ok = {b.run_id for b in cal.after if not b.error}
    drops = drop_rows(ctx.dataset)
    drops = drops[drops["run_id"].isin(ok)].reset_index(drop=True)
    runs = {r.id: r for r in ctx.dataset.runs if r.id in set(drops["run_id"])}
    if len(runs) < 2:
        return CandidateFit(cand.name, heldout_gain=0.0, heldout_gain_ci95=(0.0, 0.0), error_unit="s")
    ids = sorted(runs)
    run_of = drops["run_id"].to_numpy()
    nuisance = drops[["heading"]].to_numpy(float)
    res: dict[Shape, np.ndarray] = {}

    def simulate(shapes: list[Shape]) -> None:
        shapes = [sh for sh in dict.fromkeys(shapes) if sh not in res and (sh[:2] == (1.0, 1.0)
                                                                           or shape_values(*sh) is not None)]
        if not shapes:
            return
        ctx.say(f"fit {cand.name}: friction x{', x'.join(f'{a:g} at 1 h, x{b:g} at 48 h (tau {t:g} h)' for a, b, t in shapes)} "
                f"on {len(drops)} drops alone of {len(runs)} runs")
        jobs = [(runs[r], list(drops["fish_id"][run_of == r]),
                 cal.params if sh[:2] == (1.0, 1.0) else cand.params(cal.params, *shape_values(*sh)))
                for sh in shapes for r in ids]
        slips = resimulate_drops(ctx.dataset.line, jobs, pool=ctx.pool)
        for n, sh in enumerate(shapes):
            sim = {(r, f): v for r, d in zip(ids, slips[n * len(ids):(n + 1) * len(ids)]) for f, v in d.items()}
            res[sh] = np.array([sim[(r, f)] for r, f in zip(run_of, drops["fish_id"])]) - drops["slip_s"].to_numpy()

    base: Shape = (1.0, 1.0, 24.0)
    simulate([base] + [(f, 1.0, 24.0) for f in FRESH_X[:-1]] + [(1.0, d, 24.0) for d in DRY_X[1:3]])
    failed = ~np.isfinite(res[base])  # drops the model as calibrated cannot read are left out of every error
    for sh in res:  # a drop the extension could not simulate counts as no better than the base
        res[sh] = np.where(np.isfinite(res[sh]), res[sh], res[base])

    def errors(sh: Shape, train: np.ndarray) -> np.ndarray:
        """Per run, the squared error of its drops once the nuisance fitted on the ``train`` drops is taken out."""
        keep = train & ~failed
        b, *_ = np.linalg.lstsq(nuisance[keep], res[sh][keep], rcond=None)
        e = np.where(failed, 0.0, (res[sh] - nuisance @ b) ** 2)
        return np.array([e[run_of == r].sum() for r in ids])

    everyone = np.ones(len(drops), dtype=bool)

    def best(weight: np.ndarray, train: np.ndarray = everyone) -> Shape:
        """The shape of least weighted error (the base first: a tie keeps the base)."""
        return min([base] + [sh for sh in res if sh != base], key=lambda sh: float(errors(sh, train) @ weight))

    for _ in range(4):  # walk while the error falls
        top = best(np.ones(len(ids)))
        simulate(_neighbours(top))
        if best(np.ones(len(ids))) == top:
            break
    u, e0 = np.zeros(len(ids)), np.zeros(len(ids))
    for fold in folds(ids):
        test = np.array([r in fold for r in ids])
        train = ~np.isin(run_of, fold)
        chosen = best((~test).astype(float), train)
        e_base, e_chosen = errors(base, train), errors(chosen, train)
        u[test], e0[test] = e_base[test] - e_chosen[test], e_base[test]
    out = CandidateFit(cand.name, error_unit="s").score(heldout_score(ids, u, e0, int((~failed).sum()), ctx.rng))
    out.values = _values(best(np.ones(len(ids))))
    table = {sh: errors(sh, everyone) for sh in res}
    boot = []
    for _ in range(300):
        w = np.bincount(ctx.rng.integers(0, len(ids), len(ids)), minlength=len(ids)).astype(float)
        boot.append(_values(min([base] + [sh for sh in res if sh != base], key=lambda sh: float(table[sh] @ w))))
    for name in cand.parameters:
        out.ci95[name] = tuple(float(np.percentile([b[name] for b in boot], q)) for q in (2.5, 97.5))
    chosen = best(np.ones(len(ids)))
    out.at_grid_end = {name: f"{which} value searched ({x:g} x the calibrated friction at {h})"
                       for name, x, grid, h in (("friction_level", chosen[0], FRESH_X, "1 h"),
                                                ("gain", chosen[1], DRY_X, "48 h"))
                       for which in (("lowest",) if x == grid[0] and x != 1.0 else ("highest",) if x == grid[-1]
                                     else ())}
    if chosen[:2] != (1.0, 1.0) and chosen[2] in (TIME_CONSTANTS_H[0], TIME_CONSTANTS_H[-1]):
        out.at_grid_end["time_constant_h"] = (f"{'lowest' if chosen[2] == TIME_CONSTANTS_H[0] else 'highest'} "
                                              f"value searched ({chosen[2]:g} h)")
    return out


def _values(sh: Shape) -> dict[str, float]:
    """A shape as the extension's parameters (the base: no gain, no change of level)."""
    if sh[:2] == (1.0, 1.0):
        return {"gain": 0.0, "time_constant_h": sh[2], "friction_level": 1.0}
    gain, tau, level = shape_values(*sh)
    return {"gain": gain, "time_constant_h": tau, "friction_level": level}


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
