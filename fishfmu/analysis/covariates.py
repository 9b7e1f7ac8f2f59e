"""The covariate test every candidate cause is judged by (``docs/diagnosis.md``), whatever its quantity.

A candidate cause is a physical quantity that follows a covariate; its test (:func:`covariate_test`) compares, on
runs held out one at a time, the constant (refitted on the other runs beside the candidate: one level and the
nuisance terms, or a level per run where the covariate varies within runs) with the constant plus the covariate's
term; the *held-out gain* is the share of the held-out error the term removes
(:func:`fishfmu.analysis.fitting.heldout_score`).  The *p-value* is the chance of a term explaining at least as
much of the data (fitted on all of it) if the quantity did not follow the covariate: the same fit on data where the
covariate was shuffled where the null makes it exchangeable (``rows``: between rows, within each of the design's
strata where it has them; ``within``: within each run;
``shift``: circular shifts within each group, for a covariate that is a time series; ``strata``: ``rows`` that
requires the strata).  Each candidate's module
(:mod:`fishfmu.analysis.causes`) builds its :class:`Design` from the rows it reads and calls this test.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from fishfmu.analysis.fitting import heldout_score

PERMUTATIONS = 999
"""Shuffles per test: p-values resolve to 1/1000 where the data allow so many distinct shuffles."""


# ------------------------------------------------------------------------------------------------- tests

@dataclass
class CovariateTest:
    """One candidate's test: does letting its quantity follow its covariate beat the constant on held-out runs?"""

    candidate: str
    quantity: str
    covariate: str
    n_rows: int
    n_runs: int
    heldout_gain: float = float("nan")
    """Share of the held-out error (each run predicted from the others) the covariate's term removes."""
    heldout_gain_ci95: tuple[float, float] = (float("nan"), float("nan"))
    explained: float = float("nan")
    """Share of the constant's squared error the covariate's term removes, fitted on all rows (the test's
    statistic)."""
    p_value: float = float("nan")
    """The chance of explaining at least this much if the quantity did not follow the covariate (permutations)."""
    shape: str = ""
    """The covariate's shape chosen on all runs (e.g. ``log hours to 24 h``)."""
    slope: float = float("nan")
    """The term's coefficient on all runs, in the quantity's unit per unit of the shape."""
    effect: float = float("nan")
    """The term's size over the shape's range in the data (slope x range), in the quantity's unit."""
    min_effect: float = 0.0
    """The smallest effect worth naming (see :class:`Design`)."""
    gain_by_run: dict[str, float] = field(default_factory=dict)
    note: str = ""
    """Why it could not be judged, or what more runs would decide it."""

    @property
    def judged(self) -> bool:
        return bool(np.isfinite(self.p_value))


@dataclass(frozen=True)
class Design:
    """A test's rows: response ``y`` per row, its ``group`` (run), the covariate's candidate shapes (columns of
    ``shapes``, one chosen per fit), and nuisance columns ``nuisance`` fitted in both models. ``within``: the
    covariate varies inside a group, and each group's constant level is its own (rows centred per group);
    otherwise one level for all groups."""

    y: np.ndarray
    group: np.ndarray
    shapes: np.ndarray
    shape_names: list[str]
    nuisance: np.ndarray
    within: bool
    sign: int = 0
    """+1 / -1: only a term of this sign counts (a physical direction), 0: either."""
    min_effect: float = 0.0
    """The smallest effect worth naming, in the response's unit over the shape's range (0: any)."""
    strata: np.ndarray | None = None
    """Per row, the stratum the ``rows`` shuffle keeps it in (None: one stratum): a covariate exchangeable only
    among rows of one stratum (a belt's speed among the passages at one photo-eye: the eyes sit at belts of
    different speeds; fish touching a guide exchanging their positions along the line among themselves) is shuffled
    within each."""


def _centre(a: np.ndarray, group: np.ndarray) -> np.ndarray:
    out = a.astype(float).copy()
    for g in np.unique(group):
        m = group == g
        out[m] -= out[m].mean(axis=0)
    return out


def _lstsq(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(x, y, rcond=None)[0] if x.shape[1] else np.zeros(0)


def _group_sums(z: np.ndarray, y: np.ndarray, idx: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group: Z'Z (n_groups x p x p) and Z'y (n_groups x p), the sufficient statistics of least squares."""
    p = z.shape[1]
    zz = np.zeros((n_groups, p, p))
    zy = np.zeros((n_groups, p))
    for i in range(p):
        zy[:, i] = np.bincount(idx, weights=z[:, i] * y, minlength=n_groups)
        for j in range(i, p):
            zz[:, i, j] = zz[:, j, i] = np.bincount(idx, weights=z[:, i] * z[:, j], minlength=n_groups)
    return zz, zy


def _solve(a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Least squares from its normal equations, per fold (a: folds x p x p), singular ones by pseudo-inverse."""
    return np.einsum("fij,fj->fi", np.linalg.pinv(a), c) if a.shape[-1] else np.zeros(c.shape)


def _heldout_errors(d: Design, shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Per group: held-out squared error of the constant model and of the candidate (its shape chosen on the
    other groups by their fit), and the chosen shape per group. Least squares through per-group sufficient
    statistics: a fold's training sums are the totals less the group's."""
    groups, idx = np.unique(d.group, return_inverse=True)
    n = len(groups)
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    s = _centre(shapes, d.group) if d.within else shapes
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    ones = np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1))
    base_x = np.column_stack([ones, nu])
    yy = np.bincount(idx, weights=y * y, minlength=n)
    yy_train = yy.sum() - yy

    def errors(z: np.ndarray, sign: int) -> tuple[np.ndarray, np.ndarray]:
        zz, zy = _group_sums(z, y, idx, n)
        a, c = zz.sum(axis=0)[None] - zz, zy.sum(axis=0)[None] - zy
        b = _solve(a, c)
        if sign and z.shape[1] > base_x.shape[1]:
            wrong = np.sign(b[:, -1]) == -sign
            if wrong.any():  # a term of the wrong sign is no term: the base model's fit on those folds
                q = base_x.shape[1]
                b[wrong] = 0.0
                b[wrong, :q] = _solve(a[wrong][:, :q, :q], c[wrong][:, :q])
        held = yy - 2 * np.einsum("fi,fi->f", b, zy) + np.einsum("fi,fij,fj->f", b, zz, b)
        train = yy_train - 2 * np.einsum("fi,fi->f", b, c) + np.einsum("fi,fij,fj->f", b, a, b)
        return held, train

    e0, _ = errors(base_x, 0)
    best_held, best_train = np.full(n, np.inf), np.full(n, np.inf)
    chosen = np.zeros(n, dtype=int)
    for k in range(s.shape[1]):
        held, train = errors(np.column_stack([base_x, s[:, k]]), d.sign)
        better = train < best_train - 1e-15
        best_held[better], best_train[better], chosen[better] = held[better], train[better], k
    return e0, best_held, chosen.tolist()


def _basis(x: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the span of ``x``'s columns, as least squares sees it (its rank by ``lstsq``'s own
    cut-off): a residual is then ``y - u (u' y)``, one product for any number of columns."""
    if not x.shape[1]:
        return np.zeros((x.shape[0], 0))
    u, sv, _ = np.linalg.svd(x, full_matrices=False)
    return u[:, sv > np.finfo(float).eps * max(x.shape) * sv[0]]


def explainer(d: Design) -> Callable[[np.ndarray], float]:
    """The test statistic of ``d`` for any shapes (the observed ones and each shuffle of them): the share of the
    constant model's squared error that the best shape's term removes, fitted on all rows (the most powerful of a
    term's own fit; what it does on held-out runs is reported beside).  What a shuffle leaves alone (the response,
    the base model, its residual, the groups) is worked out once: a test runs it on up to 5000 shuffles."""
    groups, idx = np.unique(d.group, return_inverse=True)
    member = np.zeros((len(groups), len(d.y)))
    member[idx, np.arange(len(d.y))] = 1.0
    count = member.sum(axis=1)[:, None]
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    base = _basis(np.column_stack([np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1)), nu]))
    r0 = y - base @ (base.T @ y)
    ss0 = float(r0 @ r0)

    def explained(shapes: np.ndarray) -> float:
        if ss0 <= 0.0:
            return 0.0
        s = np.asarray(shapes, dtype=float).reshape(len(y), -1)
        if d.within:  # each group's mean taken off, all columns in one product
            s = s - (member @ s / count)[idx]
        sk = s - base @ (base.T @ s)  # each shape's part the base does not explain
        den = np.einsum("ij,ij->j", sk, sk)
        fits = den > 1e-300
        b = np.divide(sk.T @ r0, den, out=np.zeros(len(den)), where=fits)
        if d.sign:
            fits &= np.sign(b) != -d.sign  # a term of the wrong sign is no term
        return float(np.max(np.where(fits, b * b * den / ss0, 0.0), initial=0.0))

    return explained


def each_shape_alone(d: Design) -> list[tuple[float, float]]:
    """Per shape, fitted alone beside the nuisance on all rows: (share of the constant model's error it removes, its
    coefficient); where several shapes stand for places, how well each place would do in the chosen one's stead."""
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    s = _centre(d.shapes, d.group) if d.within else d.shapes
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    ones = np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1))
    explained = explainer(d)
    return [(explained(d.shapes[:, [k]]),
             float(_lstsq(np.column_stack([ones, nu, s[:, k]]), y)[-1])) for k in range(d.shapes.shape[1])]


def shuffler(d: Design, shuffle: str) -> Callable[[np.random.Generator], np.ndarray]:
    """The shapes under the null, one shuffle a call: hours shuffled between runs, headings within runs, loads shifted
    in time, positions among the rows of a stratum, a run's values at each stratum (a transfer) between runs.  The
    rows' groups and strata are indexed once; each call draws from ``rng`` what a shuffle needs."""
    groups, gi = np.unique(d.group, return_inverse=True)
    if shuffle in ("strata", "runs") and d.strata is None:
        raise ValueError(f"the {shuffle} shuffle needs the design's strata")
    if shuffle == "between":  # the run -> covariate map permuted: each run takes another run's shape values
        first = np.array([np.flatnonzero(gi == k)[0] for k in range(len(groups))])
        return lambda rng: d.shapes[first[rng.permutation(len(groups))][gi]]
    if shuffle == "runs":  # each run takes another run's values, stratum by stratum (a run's value at a transfer)
        _, si = np.unique(d.strata, return_inverse=True)
        n_s = int(si.max()) + 1
        keys, first_row = np.unique(gi * n_s + si, return_index=True)
        first = np.full(len(groups) * n_s, -1)
        first[keys] = first_row
        first = first.reshape(len(groups), n_s)

        def runs(rng: np.random.Generator) -> np.ndarray:
            j = first[rng.permutation(len(groups))[gi], si]
            # a run without rows at that stratum lends nothing there
            return np.where((j >= 0).reshape((-1,) + (1,) * (d.shapes.ndim - 1)), d.shapes[np.maximum(j, 0)], 0.0)
        return runs
    if shuffle in ("rows", "strata"):  # each row takes another row's covariate (of its stratum): no run-level effect
        if d.strata is None:
            return lambda rng: d.shapes[rng.permutation(len(d.shapes))]
        cells = [np.flatnonzero(d.strata == s) for s in np.unique(d.strata)]

        def rows(rng: np.random.Generator) -> np.ndarray:
            out = d.shapes.copy()
            for idx in cells:
                out[idx] = d.shapes[rng.permutation(idx)]
            return out
        return rows
    members = [np.flatnonzero(gi == k) for k in range(len(groups))]

    def within_groups(rng: np.random.Generator) -> np.ndarray:
        out = d.shapes.copy()
        for idx in members:
            if shuffle == "within":
                out[idx] = d.shapes[rng.permutation(idx)]
            else:  # "shift": circular shift in time (rows are in time order within a group)
                out[idx] = np.roll(d.shapes[idx], int(rng.integers(1, max(len(idx), 2))), axis=0)
        return out
    return within_groups


def _shuffled(d: Design, rng: np.random.Generator, shuffle: str) -> np.ndarray:
    """One shuffle of the shapes (:func:`shuffler`)."""
    return shuffler(d, shuffle)(rng)


def covariate_test(candidate: str, quantity: str, covariate: str, d: Design, shuffle: str,
                   rng: np.random.Generator, permutations: int = PERMUTATIONS) -> CovariateTest:
    groups = np.unique(d.group)
    out = CovariateTest(candidate, quantity, covariate, len(d.y), len(groups))
    if len(groups) < 3 or len(d.y) < 8:
        out.note = f"only {len(groups)} runs with {len(d.y)} rows of {quantity}: too few to judge"
        return out
    e0, e1, chosen = _heldout_errors(d, d.shapes)
    score = heldout_score(list(groups), e0 - e1, e0, len(d.y), rng)
    out.heldout_gain, out.heldout_gain_ci95, out.gain_by_run = score.gain, score.ci95, score.by_run
    explained, shuffled = explainer(d), shuffler(d, shuffle)
    observed = explained(d.shapes)
    exceed = sum(explained(shuffled(rng)) >= observed - 1e-12 for _ in range(permutations))
    out.explained = observed
    out.p_value = (1 + exceed) / (1 + permutations)
    # the shape and coefficient fitted on all runs
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    s = _centre(d.shapes, d.group) if d.within else d.shapes
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    ones = np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1))
    best = max(set(chosen), key=chosen.count)
    b = _lstsq(np.column_stack([ones, nu, s[:, best]]), y)
    out.shape, out.slope = d.shape_names[best], float(b[-1])
    out.effect = abs(out.slope) * float(np.ptp(d.shapes[:, best]))
    out.min_effect = d.min_effect
    return out



def against_model(measured: pd.DataFrame, model: pd.DataFrame, column: str, sign: int,
                  min_effect: float = 0.0) -> Design:
    """Rows of the measured runs against those of the same runs re-simulated with the calibrated model, compared
    within each run by the rank of ``column`` among both: the rows are not matched one to one (a pile's chaos decides
    which pair of fish parts, the physics how many), and a pair held together and one that parted differ by rank,
    not by how far the parted one went. The term: measured (1) or modelled (0), shuffled among a run's rows (the
    ``within`` shuffle). Only the runs both have."""
    both = pd.concat([measured.assign(measured=1.0), model.assign(measured=0.0)], ignore_index=True)
    both = both[both["run_id"].isin(set(measured["run_id"]) & set(model["run_id"]))]
    both = both.sort_values(["run_id", "measured"], kind="stable")
    rank = both.groupby("run_id")[column].rank(pct=True).to_numpy(float)
    return Design(rank, both["run_id"].to_numpy(), both[["measured"]].to_numpy(float), ["measured (1) or modelled (0)"],
                  np.zeros((len(both), 0)), within=True, sign=sign, min_effect=min_effect)


def run_clustered_test(candidate: str, quantity: str, covariate: str, d: Design, rng: np.random.Generator
                       ) -> CovariateTest:
    """The term's coefficient against its spread between runs (each run left out in turn: the jackknife's standard
    error), its p-value from Student's t with one fewer degrees of freedom than runs, times the number of shapes
    offered (the best one is taken). For a term a shuffle cannot judge at a scan's threshold: one level at one of
    three places, each run's places swapped among themselves, has at least ``3 x 3^-runs`` of its shuffles give the
    observed split again (5e-4 with eight runs). The held-out gain is :func:`covariate_test`'s."""
    out = covariate_test(candidate, quantity, covariate, d, "within", rng, permutations=0)  # its held-out gain
    if not out.judged:
        return out
    groups = np.unique(d.group)
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    s = _centre(d.shapes, d.group) if d.within else d.shapes
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    ones = np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1))
    best = (-np.inf, 0, 0.0)
    for k in range(s.shape[1]):
        x = np.column_stack([ones, nu, s[:, k]])
        b = float(_lstsq(x, y)[-1])
        left = np.array([_lstsq(x[d.group != g], y[d.group != g])[-1] for g in groups])
        se = float(np.sqrt((len(groups) - 1) / len(groups) * np.sum((left - left.mean()) ** 2)))
        t = b / se if se > 0 else (np.inf if b else 0.0)
        t = t if d.sign == 0 else d.sign * t
        t = abs(t) if d.sign == 0 else t
        if t > best[0]:
            best = (t, k, b)
    t, k, b = best
    one_sided = stats.t.sf(t, len(groups) - 1)
    out.p_value = float(min(1.0, s.shape[1] * (one_sided if d.sign else 2.0 * one_sided)))
    out.shape, out.slope = d.shape_names[k], b
    out.effect = abs(b) * float(np.ptp(d.shapes[:, k]))
    out.explained = each_shape_alone(d)[k][0]
    return out


# ------------------------------------------------------------------------------------------------- shapes and responses

def log_hours_shapes(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Monotone shapes of hours post mortem: log-time from 1 h saturating at 8, 24 or 72 h (drying)."""
    h = np.maximum(h, 0.1)
    cols, names = [], []
    for end in (8.0, 24.0, 72.0):
        cols.append(np.clip(np.log(h) / np.log(end), 0.0, 1.0))
        names.append(f"log hours, from 1 h, level from {end:g} h")
    return np.column_stack(cols), names


def bump_shapes(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Shapes that come and go with hours post mortem (rigor sets in, holds, resolves): a bump in log-time
    peaking at 6-36 h, narrow or wide, and a rise that does not resolve within the data."""
    lh = np.log(np.maximum(h, 0.1))
    cols, names = [], []
    for peak in (6.0, 12.0, 24.0, 36.0):
        for width in (0.7, 1.2):
            cols.append(np.exp(-((lh - np.log(peak)) / width) ** 2))
            names.append(f"bump peaking at {peak:g} h (width x{np.exp(width):.1f})")
    return np.column_stack(cols), names


def robust(y: np.ndarray) -> np.ndarray:
    """Clip a response to its median +- 3 scaled MADs: one tracker glitch or a drop that bounced must not decide a
    test."""
    med = float(np.median(y))
    mad = 1.4826 * float(np.median(np.abs(y - med))) or float(np.std(y)) or 1.0
    return np.clip(y, med - 3 * mad, med + 3 * mad)


