"""Run-level effects fitted from how each fish's residual moves with a level, not from a grid per candidate.

Friction that changes with hours post mortem (mucus) and joints that stiffen with it (rigor) act on a
whole run through one number each: the run's friction multiplier on belts and guides, and its fish's
extra joint stiffness.  So the fit runs (fish riding alone) are simulated a few times, each run at a
few values of each **level** (:data:`FRICTION`, :data:`RIGOR`) around the calibrated model (once more
beyond an end of the grid where a run still wants more), and for every residual row (one fish after one
transfer) the lag is interpolated linearly between them, in log of the multiplier for friction and
log(1 + stiffness) for rigor.
Levels act on different things (how long a fish slips, how it bends over a gap); their changes of a
row's lag are added.

Every **model of the levels across runs** (:data:`MODELS`) is then a function from a few parameters and
each run's hours post mortem to its levels, and is fitted and cross-validated on these interpolated
residuals without another simulation:

- ``constant``: one friction multiplier and one joint stiffening k0 for every run (the base model's
  calibration, no effect: the independent simulator's fish land and bend as if stiffer than ours in
  every run, whatever their age);
- ``mucus_friction``: that multiplier times (1 + gain x mucus index(hours)), friction that changes as
  the mucus dries (monotone in hours post mortem), with the constant k0;
- ``rigor_mortis``: the constant multiplier, and joints (1 + k0 + K x rigor index(hours)) times stiffer
  (rigor sets in, peaks and resolves: not monotone).

A model's parameters are chosen by exhaustive search over a fine grid; its held-out error is that of
each run with the parameters chosen on the other runs (leave one run out).  A candidate's gain is the
held-out error it removes relative to ``constant`` (which has one parameter fewer; choosing parameters
on other runs is the penalty for having more).  The levels each run prefers on its own are kept as
the signature a user can look at: mucus predicts friction rising with hours, rigor a stiffness that
comes and goes, a base mismatch the same level everywhere.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.extensions import stiffening_limit_loss
from plant.params import PlantParams

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
    grid: tuple[float, float]
    """Two values simulated besides ``off`` (one below, one above)."""
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
RIGOR = Level("rigor", 0.0, (5.0, 20.0), (0.0, 50.0), np.log1p, _rigor_level)
"""Extra joint stiffness, x the soft one, with the range lost that goes with it (what rigor changes)."""
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
    """Each row's lag with every level off [m]."""
    values: dict[str, np.ndarray] = field(default_factory=dict)
    """Per level: the simulated values (sorted, ``off`` among them)."""
    delta: dict[str, np.ndarray] = field(default_factory=dict)
    """Per level: (rows x values) change of each row's lag from ``off``."""

    def range(self, name: str) -> tuple[float, float]:
        return float(self.values[name][0]), float(self.values[name][-1])

    def run_ss(self, levels: dict[str, np.ndarray]) -> np.ndarray:
        """Sum of squared lags per run with each run at the given levels (missing levels: off; outside the
        simulated values: at the nearest end)."""
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
        return np.bincount(self.row_run, weights=lag**2, minlength=len(self.runs))

    @property
    def counts(self) -> np.ndarray:
        return np.bincount(self.row_run, minlength=len(self.runs))


def _rows(res: RunResiduals) -> pd.DataFrame:
    free = alone(res.rows)
    free = free[free["belt"] > 0]  # after a transfer: on the first belt the lag is the drop's
    return free.set_index(["fish_id", "belt"])["lag_m"].astype(float)


def responses(off: dict[str, RunResiduals], simulated: dict[tuple[str, float], dict[str, RunResiduals]],
              hours: dict[str, float]) -> Responses:
    """Rows of ``off`` (the fit runs with every level off) and their lags at each simulated (level, value);
    a row a simulation lost (or a failed simulation) keeps its lag from ``off``."""
    runs = sorted(off)
    row_run, lag0, keys = [], [], []
    for i, r in enumerate(runs):
        s = _rows(off[r]).dropna()
        row_run += [i] * len(s)
        lag0 += list(s.to_numpy())
        keys.append(s.index)
    resp = Responses(runs, np.array([hours[r] for r in runs], float), np.array(row_run, dtype=np.int64),
                     np.array(lag0, float))
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
                s = _rows(res).reindex(idx) if res is not None and not res.error else pd.Series(np.nan, index=idx)
                col.append(s.to_numpy(float))
            v = np.concatenate(col) if col else np.zeros(0)
            lags.append(np.where(np.isfinite(v), v, resp.lag0))
        resp.values[name] = np.array(values, float)
        resp.delta[name] = np.array(lags).T - resp.lag0[:, None]  # rows x values, zero at off
    return resp


@dataclass(frozen=True)
class LevelModel:
    """Levels of every run from a few parameters and the runs' hours post mortem."""

    name: str
    parameters: tuple[str, ...]
    grids: Callable[[Responses], tuple[np.ndarray, ...]]
    """Values searched per parameter, given the levels simulated."""
    levels: Callable[..., dict[str, np.ndarray]]
    """``levels(hours, *values) -> {level: per-run value}``."""


def mucus_index(hours: np.ndarray, time_constant_h: float = 24.0) -> np.ndarray:
    """How far the mucus has dried (0 fresh, towards 1) at the plant's default time constant."""
    return 1.0 - np.exp(-np.asarray(hours, dtype=float) / time_constant_h)


def rigor_index(hours: np.ndarray, peak_h: float = 24.0, width_h: float = 20.0) -> np.ndarray:
    """How far rigor has set in (0..1, 1 at its peak) at the plant's default onset and duration."""
    return np.exp(-(((np.asarray(hours, dtype=float) - peak_h) / width_h) ** 2))


def _friction_values(resp: Responses) -> np.ndarray:
    return np.geomspace(*resp.range("friction"), 25)


def _stiffness_values(resp: Responses) -> np.ndarray:
    """Joint stiffening levels searched (only 0 when rigor was not simulated)."""
    if "rigor" not in resp.values:
        return np.zeros(1)
    return np.concatenate([[0.0], np.geomspace(0.3, resp.range("rigor")[1], 15)])


def _const(h: np.ndarray, value: float) -> np.ndarray:
    return np.full(len(h), float(value))


MODELS: dict[str, LevelModel] = {m.name: m for m in (
    LevelModel("constant", ("friction_level", "joint_stiffening"), lambda r: (_friction_values(r), _stiffness_values(r)),
               lambda h, a, k0: {"friction": _const(h, a), "rigor": _const(h, k0)}),
    LevelModel("mucus_friction", ("friction_level", "joint_stiffening", "gain"),
               lambda r: (_friction_values(r), _stiffness_values(r), np.linspace(-0.8, 2.0, 29)),
               lambda h, a, k0, g: {"friction": a * (1.0 + g * mucus_index(h)), "rigor": _const(h, k0)}),
    LevelModel("rigor_mortis", ("friction_level", "joint_stiffening", "stiffness_gain"),
               lambda r: (_friction_values(r), _stiffness_values(r), _stiffness_values(r)),
               lambda h, a, k0, k: {"friction": _const(h, a), "rigor": k0 + k * rigor_index(h)}),
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


def _table(model: LevelModel, resp: Responses) -> tuple[list[tuple[float, ...]], np.ndarray]:
    """Every parameter combination of the model's grid and its sum of squares per run."""
    combos = list(itertools.product(*model.grids(resp)))
    return combos, np.array([resp.run_ss(model.levels(resp.hours, *c)) for c in combos])


def fit_model(model: LevelModel, resp: Responses, rng: np.random.Generator, n_boot: int = 300) -> ModelFit:
    combos, ss = _table(model, resp)
    n = len(resp.runs)
    best = int(np.argmin(ss.sum(axis=1)))
    cv = np.zeros(n)
    for j in range(n):  # leave one run out
        others = np.arange(n) != j
        cv[j] = ss[int(np.argmin(ss[:, others].sum(axis=1))), j] if others.any() else ss[best, j]
    boot = np.array([combos[int(np.argmin(ss[:, rng.integers(0, n, n)].sum(axis=1)))] for _ in range(n_boot)])
    values = dict(zip(model.parameters, map(float, combos[best])))
    ci = {p: (float(np.percentile(boot[:, k], 2.5)), float(np.percentile(boot[:, k], 97.5)))
          for k, p in enumerate(model.parameters)}
    return ModelFit(model.name, values, ci, ss[best], cv)


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
