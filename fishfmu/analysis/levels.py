"""Run-level effects fitted from how each fish's residual moves with a level, not from a grid per candidate.

Friction that changes with hours post mortem (mucus) and joints that stiffen with it (rigor) act on a
whole run through one number each: the run's friction multiplier on belts and guides, and its fish's
extra joint stiffness.  So the fit runs (fish riding alone) are simulated a few times, each run at a
few values of each **level** (:data:`FRICTION`, :data:`RIGOR`) around the calibrated model (once more
beyond an end of the grid where a run still wants more), and every response row is interpolated
linearly between them, in log of the multiplier for friction and log(1 + stiffness) for rigor.  Levels
act on different things (how long a fish slips, how it bends and lies); their changes of a row add up.

Rows of three kinds (:data:`LAG`, :data:`DROP`, :data:`PASSAGE`):

- a fish's **lag** across a transfer (what friction decides, and stiffness a little);
- a fish's lag after its **drop** onto the infeed with no other fish near: how long it slides until it moves
  with the belt.  The whole fish slides on one belt, so it keeps answering to friction where the lags
  across transfers no longer do (a fish that grips lags the same at a transfer whatever the friction above a
  point: the faster belt takes it when half of it lies there).  How a drop is modelled (height, landing)
  differs from a real drop by an offset, so these rows too are taken less their mean over the runs: they
  say how friction differs between runs, not its level;
- a beam's **blocked share** of the passages of fish riding alone
  (:func:`fishfmu.analysis.residuals.passage_residuals`): a limp fish lies in the belt and blocks a low
  beam throughout, one stiff in rigor does not and the beam flickers.  Friction hardly changes it.  How a
  beam sees our fish's outline differs from a real beam's by an offset of its own, so each beam's rows are
  taken less their mean over the runs: only the differences between runs count.

Each row is weighted by 1 / its noise variance (a beam's standard error over its fish; the lags' mean
square at the best simulated constant level), so metres and shares add up as what they are worth.

Every **model of the levels across runs** (:data:`MODELS`) is then a function from a few parameters and
each run's hours post mortem to its levels, and is fitted and cross-validated on these interpolated
residuals without another simulation:

- ``constant``: one friction multiplier and one joint stiffening k0 for every run (the base model's
  calibration, no effect: the independent simulator's fish land and bend as if stiffer than ours in
  every run, whatever their age);
- ``mucus_friction``: that multiplier times (1 + gain x mucus index(hours, time constant)), friction
  that changes as the mucus dries (monotone in hours post mortem), with the constant k0; judged on the
  lags only (the rows friction changes);
- ``rigor_mortis``: the constant multiplier, and joints (1 + k0 + K x rigor index(hours, peak, width))
  times stiffer (rigor sets in, peaks and resolves: not monotone); judged on lags and beams.

The timing of each effect (mucus's time constant, rigor's peak and width) is searched on a coarse grid
with its strength: it depends on the slaughter and the cold chain, which no model knows.  A model's
parameters are chosen by exhaustive search over the grid; its held-out error is that of each run with
the parameters chosen on the other runs (leave one run out).  A candidate's gain is the held-out error
it removes relative to ``constant`` on the same rows (choosing its extra parameters on other runs is
the penalty for having them).  The levels each run prefers on its own are kept as the signature a user
can look at: mucus predicts friction rising with hours, rigor a stiffness that comes and goes, a base
mismatch the same level everywhere.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from plant.fish.extensions import stiffening_limit_loss
from plant.sim.params import PlantParams

from fishfmu.analysis.fitting import gain_with_ci
from fishfmu.analysis.residuals import RunResiduals, alone


rigor_limit_loss = stiffening_limit_loss
"""One strength for both effects of rigor: the fraction of joint range lost at full rigor that goes with a
stiffness of (1 + ``stiffness_gain``) x the soft one (the plant's law for ``joints.stiffening``)."""


def _friction_level(p: PlantParams, m: float, hours: float) -> None:
    p.friction.fish_belt = float(p.friction.fish_belt * m)
    p.friction.fish_guide = float(p.friction.fish_guide * m)


def _rigor_level(p: PlantParams, k: float, hours: float) -> None:
    p.joints.stiffening = float(k)  # every fish of the run (1 + k) x stiffer, with the range lost that goes with it


@dataclass(frozen=True)
class Level:
    """One number per run that an effect sets (see the module docstring)."""

    name: str
    off: float
    grid: tuple[float, ...]
    """Values simulated besides ``off``: on both sides of it, or above it when ``off`` is the lower bound."""
    bounds: tuple[float, float]
    """How far the grid may be extended."""
    to_x: Callable[[np.ndarray], np.ndarray]
    """The coordinate a row's lag is interpolated in."""
    apply: Callable[[PlantParams, float, float], None]
    """``apply(params, value, hours)``: the run's parameters at this level."""

    def params(self, base: PlantParams, value: float, hours: float) -> PlantParams:
        p = base.model_copy(deep=True)
        self.apply(p, value, hours)
        return p

    def beyond(self, values: list[float], low: bool) -> float | None:
        """The next value beyond the lowest (``low``) or highest of ``values``: as far again in the level's
        coordinate as the step to it, within the bounds (None: at the bound already)."""
        xs = np.sort(self.to_x(np.array(values, float)))
        x = xs[0] - (xs[1] - xs[0]) if low else xs[-1] + (xs[-1] - xs[-2])
        grid = np.linspace(*self.bounds, 2001)  # back from the coordinate, within the bounds
        v = float(grid[int(np.argmin(np.abs(self.to_x(grid) - x)))])
        return None if v in values or (v <= min(values) if not low else v >= max(values)) else round(v, 4)


FRICTION = Level("friction", 1.0, (0.4, 1.4), (0.2, 3.0), np.log, _friction_level)
"""Multiplier of fish-belt and fish-guide friction (what mucus changes)."""
RIGOR = Level("rigor", 0.0, (1.0, 2.5, 20.0), (0.0, 50.0), np.log1p, _rigor_level)
"""Extra joint stiffness, x the soft one, with the range lost that goes with it (what rigor changes).  Our fish's
response bends early: measured with values up to x41 (eight datasets of the independent simulator, distance of the
rows, over their noise, from their value at x41), a beam's blocked share and the lags have made a fifth to a third
of their change by x2, 58-81 % by x3.5, 72-91 % by x6 and 93-98 % by x11 (a joint is no stiffer than its limit
stiffness, which the explicit step sets: the paper's fish's joints reach it between x3 and x35).  So the values
simulated sample the bend (x2, x3.5) and the far end (x21): with x6 and x21 alone a run at x2 was interpolated at a
third of its change.
With one value at x9 a strong rigor (x16, 70 % of the range lost) was no longer found in the synthetic test, its
runs' responses cut off at x9."""
LEVELS = {lv.name: lv for lv in (FRICTION, RIGOR)}


@dataclass
class Responses:
    """The lag of every residual row of the fit runs as a function of the levels (see the module docstring)."""

    runs: list[str]
    hours: np.ndarray
    """Hours post mortem of each run."""
    row_run: np.ndarray
    """Index into ``runs`` of each row."""
    lag0: np.ndarray
    """Each row's residual with every level off (a lag [m], or a photo-eye blocked share)."""
    row_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Per row: :data:`LAG`, :data:`DROP` or :data:`PASSAGE`."""
    row_offset_group: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Per row: the group whose mean over all runs is taken off (each beam's photo-eye rows, the drop rows;
    -1: none, the lags across transfers)."""
    row_weight: np.ndarray = field(default_factory=lambda: np.ones(0))
    """Per row: 1 / its noise variance (a lag: the lags' mean square at the best simulated constant level; a drop:
    the drops' scatter within a run there; a beam: its standard error squared), so that metres and blocked shares
    add up as what they are worth."""
    values: dict[str, np.ndarray] = field(default_factory=dict)
    """Per level: the simulated values (sorted, ``off`` among them)."""
    delta: dict[str, np.ndarray] = field(default_factory=dict)
    """Per level: (rows x values) change of each row's lag from ``off``."""

    def range(self, name: str) -> tuple[float, float]:
        return float(self.values[name][0]), float(self.values[name][-1])

    def residuals(self, levels: dict[str, np.ndarray]) -> np.ndarray:
        """Every row's residual with each run at the given levels (missing levels: off; outside the simulated
        values: at the nearest end); photo-eye rows less their beam's mean over all runs, drop rows less theirs."""
        lag = self.lag0.copy()
        rows = np.arange(len(lag))
        for name, per_run in levels.items():
            if name not in self.values:  # a level not simulated can only be off
                if np.any(np.asarray(per_run, float) != LEVELS[name].off):
                    raise ValueError(f"level {name} was not simulated")
                continue
            lv, xs, d = LEVELS[name], LEVELS[name].to_x(self.values[name]), self.delta[name]
            x = lv.to_x(np.clip(np.asarray(per_run, float), *self.range(name)))[self.row_run]
            j = np.clip(np.searchsorted(xs, x, side="right") - 1, 0, len(xs) - 2)
            w = np.clip((x - xs[j]) / (xs[j + 1] - xs[j]), 0.0, 1.0)
            lag += d[rows, j] * (1.0 - w) + d[rows, j + 1] * w
        for g in range(int(self.row_offset_group.max(initial=-1)) + 1):  # how a beam sees our outline, how a drop is modelled
            rows_b = (self.row_offset_group == g) & (self.row_weight > 0)
            if rows_b.any():
                lag[rows_b] -= np.average(lag[rows_b], weights=self.row_weight[rows_b])
        return lag

    def only(self, kinds: tuple[int, ...]) -> "Responses":
        """The same responses with the rows of other kinds left out (weight 0)."""
        return replace(self, row_weight=np.where(np.isin(self.row_kind, kinds), self.row_weight, 0.0))

    def run_ss(self, levels: dict[str, np.ndarray]) -> np.ndarray:
        """Weighted sum of squared residuals per run (:attr:`row_weight`) at the given levels."""
        r = self.residuals(levels)
        return np.bincount(self.row_run, weights=self.row_weight * r**2, minlength=len(self.runs))

    def lag_ss(self, levels: dict[str, np.ndarray]) -> np.ndarray:
        """Sum of squared lags [m^2] per run at the given levels (no photo-eye rows, unweighted)."""
        r = self.residuals(levels)
        lag = self.row_kind == LAG
        return np.bincount(self.row_run[lag], weights=r[lag] ** 2, minlength=len(self.runs))

    @property
    def counts(self) -> np.ndarray:
        """Lag rows per run."""
        return np.bincount(self.row_run[self.row_kind == LAG], minlength=len(self.runs))


LAG, PASSAGE, DROP = 0, 1, 2
"""Kinds of response rows: a fish's lag across a transfer, a beam's blocked share of passages (per run), a fish's
lag after its drop."""
ROW_KINDS = {"lag": LAG, "blocked": PASSAGE, "drop": DROP}


def _rows(res: RunResiduals) -> tuple[pd.Series, pd.Series]:
    """A run's response rows, ("lag", fish, belt), ("drop", fish, "0") and ("blocked", beam, ""), and their standard
    errors (lags and drops: NaN, set from all of them)."""
    free = alone(res.rows)
    kind = np.where(free["belt"].to_numpy() > 0, "lag", "drop")  # on the first belt the lag is the drop's
    lags = pd.Series(free["lag_m"].to_numpy(float),
                     index=pd.MultiIndex.from_arrays([kind, free["fish_id"].astype(str), free["belt"].astype(str)]))
    p = res.passages
    at = pd.MultiIndex.from_arrays([["blocked"] * len(p), p["sensor_id"].astype(str), [""] * len(p)])
    beams = pd.Series(p["dblocked"].to_numpy(float), index=at)
    if not len(beams):
        return lags, pd.Series(np.nan, index=lags.index)
    return pd.concat([lags, beams]), pd.concat([pd.Series(np.nan, index=lags.index),
                                                pd.Series(p["se"].to_numpy(float), index=at)])


def responses(off: dict[str, RunResiduals], simulated: dict[tuple[str, float], dict[str, RunResiduals]],
              hours: dict[str, float]) -> Responses:
    """Rows of ``off`` (the fit runs with every level off) and their lags at each simulated (level, value).
    A run need not be simulated at every value (a grid is extended only for the runs whose own best level lies at
    its end); a row without a lag at a value (not simulated there, lost by the simulation, or a failed simulation)
    takes its change from the nearest value it has, ``off`` at least: held at its end, as beyond the grid."""
    runs = sorted(off)
    row_run, lag0, keys, kind, se = [], [], [], [], []
    for i, r in enumerate(runs):
        s, e = _rows(off[r])
        s = s.dropna()
        row_run += [i] * len(s)
        lag0 += list(s.to_numpy())
        se += list(e.reindex(s.index).to_numpy(float))
        kind += [ROW_KINDS[k] for k in s.index.get_level_values(0)]
        keys.append(s.index)
    resp = Responses(runs, np.array([hours[r] for r in runs], float), np.array(row_run, dtype=np.int64),
                     np.array(lag0, float), np.array(kind, dtype=np.int64))
    # each beam's rows and the drop rows are a group with an offset of its own (named by the beam, or ("drop",))
    group_of = [(k[0], k[1]) if k[0] == "blocked" else ("drop",) if k[0] == "drop" else None for idx in keys for k in idx]
    groups = sorted({g for g in group_of if g is not None})
    resp.row_offset_group = np.array([groups.index(g) if g is not None else -1 for g in group_of], dtype=np.int64)
    for name in sorted({n for n, _ in simulated}):
        lv = LEVELS[name]
        values = sorted({lv.off, *(v for n, v in simulated if n == name)})
        lags = []
        for value in values:
            if value == lv.off:
                lags.append(resp.lag0)
                continue
            col = []
            for r, idx in zip(runs, keys):
                res = simulated[(name, value)].get(r)
                s = _rows(res)[0].reindex(idx) if res is not None and not res.error else pd.Series(np.nan, index=idx)
                col.append(s.to_numpy(float))
            lags.append(np.concatenate(col) if col else np.zeros(0))
        resp.values[name] = np.array(values, float)
        resp.delta[name] = _nearest_filled(np.array(lags).T - resp.lag0[:, None], lv.to_x(resp.values[name]))
    resp.row_weight = _row_weights(resp, np.array(se, float))
    return resp


def _nearest_filled(delta: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """``delta`` (rows x values) with each missing entry taken from the nearest value (in ``xs``) of its row that
    has one (the ``off`` column always has: zero)."""
    out = delta.copy()
    for i, j in zip(*np.nonzero(~np.isfinite(delta))):
        have = np.flatnonzero(np.isfinite(delta[i]))
        out[i, j] = delta[i, have[int(np.argmin(np.abs(xs[have] - xs[j])))]]
    return out


def _row_weights(resp: Responses, se: np.ndarray) -> np.ndarray:
    """1 / noise variance of each row: a beam's from its standard error; the lags' their mean square at the best
    simulated pair of constant levels (what no level removes is taken for noise); the drops' their scatter within
    each run there (a run-level effect moves a run's drops together: only the scatter within a run is noise)."""
    lag, drop = resp.row_kind == LAG, resp.row_kind == DROP
    resp.row_weight = np.where(lag | drop, 1.0, 1.0 / np.square(np.where(np.isfinite(se), se, 1.0)))
    best, best_r = np.inf, None
    for combo in itertools.product(*(resp.values[n] for n in sorted(resp.values))):
        r = resp.residuals({n: np.full(len(resp.runs), v) for n, v in zip(sorted(resp.values), combo)})
        ms = float(np.mean(r[lag] ** 2)) if lag.any() else np.inf
        if ms < best:
            best, best_r = ms, r
    w = np.where(lag, 1.0 / max(best, 1e-12) if np.isfinite(best) else 1.0, resp.row_weight)
    if drop.any():
        best_r = best_r if best_r is not None else resp.residuals({})  # no lags to choose the levels by: off
        runs_d = resp.row_run[drop]
        d = best_r[drop]
        mean = np.bincount(runs_d, weights=d, minlength=len(resp.runs)) / np.maximum(
            np.bincount(runs_d, minlength=len(resp.runs)), 1)
        dof = int(drop.sum()) - len(np.unique(runs_d))
        var = float(np.sum((d - mean[runs_d]) ** 2) / dof) if dof > 0 else np.inf
        w = np.where(drop, 1.0 / max(var, 1e-12) if np.isfinite(var) else 0.0, w)
    return w


@dataclass(frozen=True)
class LevelModel:
    """Levels of every run from a few parameters and the runs' hours post mortem."""

    name: str
    parameters: tuple[str, ...]
    grids: Callable[[Responses], tuple[np.ndarray, ...]]
    """Values searched per parameter, given the levels simulated."""
    levels: Callable[..., dict[str, np.ndarray]]
    """``levels(hours, *values) -> {level: per-run value}``."""
    kinds: tuple[int, ...] = (LAG, PASSAGE)
    """The rows it is judged on (:data:`LAG`, :data:`DROP`, :data:`PASSAGE`): the ones its levels change (friction
    hardly changes how a beam sees a fish; the drops, less their mean over the runs, say how friction differs
    between runs, which one level for all runs does not change; rows a model cannot change only add noise to its
    gain)."""


def mucus_index(hours: np.ndarray, time_constant_h: float = 24.0) -> np.ndarray:
    """How far the mucus has dried (0 fresh, towards 1); by default at the plant's default time constant."""
    return 1.0 - np.exp(-np.asarray(hours, dtype=float) / time_constant_h)


def rigor_index(hours: np.ndarray, peak_h: float = 24.0, width_h: float = 20.0) -> np.ndarray:
    """How far rigor has set in (0..1, 1 at its peak); by default at the plant's default peak and duration."""
    return np.exp(-(((np.asarray(hours, dtype=float) - peak_h) / width_h) ** 2))


def _friction_values(resp: Responses) -> np.ndarray:
    return np.geomspace(*resp.range("friction"), 25)


def _stiffness_values(resp: Responses) -> np.ndarray:
    """Joint stiffening levels searched (only 0 when rigor was not simulated)."""
    if "rigor" not in resp.values:
        return np.zeros(1)
    return np.concatenate([[0.0], np.geomspace(0.3, resp.range("rigor")[1], 15)])


MUCUS_GAINS = np.concatenate([np.linspace(0.0, 2.0, 11), np.geomspace(2.5, 8.0, 6)])
"""Mucus gains searched: friction once dried up to 9 x that of a fresh fish (fresh slaughter mucus can make a
fish slide on a belt it grips a day later).  Never below zero: physics fixes the sign (the mucus dries, friction
rises), as the candidate's test does (slips that fall with hours); a model with friction falling with age would
fit a base mismatch, not mucus."""


MUCUS_TIME_CONSTANTS_H = np.array([4.0, 8.0, 16.0, 24.0, 48.0, 96.0])
"""How fast the mucus dries, searched with the gain: within hours in a dry hall, over days on ice."""
RIGOR_PEAKS_H = np.array([6.0, 12.0, 18.0, 24.0, 36.0, 48.0])
RIGOR_WIDTHS_H = np.array([10.0, 20.0, 40.0])
"""When rigor is strongest and how long it lasts, searched with its strength: rigor's timing depends on the
fish's stress at slaughter and its temperature, from half a day to two days to its peak."""


def _const(h: np.ndarray, value: float) -> np.ndarray:
    return np.full(len(h), float(value))


MODELS: dict[str, LevelModel] = {m.name: m for m in (
    LevelModel("constant", ("friction_level", "joint_stiffening"), lambda r: (_friction_values(r), _stiffness_values(r)),
               lambda h, a, k0: {"friction": _const(h, a), "rigor": _const(h, k0)}),
    LevelModel("mucus_friction", ("friction_level", "joint_stiffening", "gain", "time_constant_h"),
               lambda r: (_friction_values(r), _stiffness_values(r), MUCUS_GAINS, MUCUS_TIME_CONSTANTS_H),
               lambda h, a, k0, g, tau: {"friction": a * (1.0 + g * mucus_index(h, tau)), "rigor": _const(h, k0)},
               kinds=(LAG, DROP)),
    LevelModel("rigor_mortis", ("friction_level", "joint_stiffening", "stiffness_gain", "peak_h", "width_h"),
               lambda r: (_friction_values(r), _stiffness_values(r), _stiffness_values(r), RIGOR_PEAKS_H, RIGOR_WIDTHS_H),
               lambda h, a, k0, k, peak, width: {"friction": _const(h, a), "rigor": k0 + k * rigor_index(h, peak, width)}),
)}
"""The models of levels across runs; ``constant`` is the reference (no effect)."""


@dataclass
class ModelFit:
    name: str
    values: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    ss: np.ndarray
    """Per run: sum of squares with the values fitted on all runs."""
    cv_ss: np.ndarray
    """Per run: sum of squares with the values fitted on the other runs."""
    cv_values: list[dict[str, float]] = field(default_factory=list)
    """Per run: the values fitted on the other runs (what the run is predicted with when held out)."""


def _table(model: LevelModel, resp: Responses, fixed: dict[str, float] | None = None
           ) -> tuple[list[tuple[float, ...]], np.ndarray]:
    """Every parameter combination of the model's grid (``fixed`` parameters at their value) and its sum of squares
    per run."""
    grids = [np.array([fixed[p]]) if fixed and p in fixed else g for p, g in zip(model.parameters, model.grids(resp))]
    combos = list(itertools.product(*grids))
    return combos, np.array([resp.run_ss(model.levels(resp.hours, *c)) for c in combos])


def fit_model(model: LevelModel, resp: Responses, rng: np.random.Generator, n_boot: int = 300,
              fixed: dict[str, float] | None = None) -> ModelFit:
    """The model's parameters by exhaustive search over its grid (``fixed``: held at these values), with a bootstrap
    interval over runs and each run's held-out error (its parameters chosen on the other runs)."""
    combos, ss = _table(model, resp, fixed)
    n = len(resp.runs)
    best = int(np.argmin(ss.sum(axis=1)))
    cv, chosen = np.zeros(n), np.full(n, best)
    for j in range(n):  # leave one run out
        others = np.arange(n) != j
        if others.any():
            chosen[j] = int(np.argmin(ss[:, others].sum(axis=1)))
        cv[j] = ss[chosen[j], j]
    boot = np.array([combos[int(np.argmin(ss[:, rng.integers(0, n, n)].sum(axis=1)))] for _ in range(n_boot)])
    values = dict(zip(model.parameters, map(float, combos[best])))
    ci = {p: (float(np.percentile(boot[:, k], 2.5)), float(np.percentile(boot[:, k], 97.5)))
          for k, p in enumerate(model.parameters)}
    return ModelFit(model.name, values, ci, ss[best], cv,
                    [dict(zip(model.parameters, map(float, combos[c]))) for c in chosen])


def gain_over(reference: ModelFit, fit: ModelFit, rng: np.random.Generator) -> tuple[float, tuple[float, float]]:
    """Fraction of the reference's held-out error the model removes, with a bootstrap interval over runs."""
    return gain_with_ci(reference.cv_ss - fit.cv_ss, reference.cv_ss, rng)


def run_levels(resp: Responses) -> pd.DataFrame:
    """The signature: each run's own best friction level (rigor off) and best rigor level (friction at the
    constant fit), with its hours post mortem."""
    rows = []
    a_grid = _friction_values(resp)
    ss_a = np.array([resp.run_ss({"friction": np.full(len(resp.runs), a)}) for a in a_grid])
    a_all = float(a_grid[int(np.argmin(ss_a.sum(axis=1)))])
    k_grid = _stiffness_values(resp) if "rigor" in resp.values else None
    ss_k = (np.array([resp.run_ss({"friction": np.full(len(resp.runs), a_all), "rigor": np.full(len(resp.runs), k)})
                      for k in k_grid]) if k_grid is not None else None)
    for j, r in enumerate(resp.runs):
        rows.append({"run_id": r, "hours_post_mortem": float(resp.hours[j]), "rows": int(resp.counts[j]),
                     "friction_level": float(a_grid[int(np.argmin(ss_a[:, j]))]),
                     "rigor_level": float(k_grid[int(np.argmin(ss_k[:, j]))]) if ss_k is not None else np.nan})
    return pd.DataFrame(rows)
