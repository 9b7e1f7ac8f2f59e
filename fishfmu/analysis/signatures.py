"""Whether each candidate cause's quantity follows its covariate beyond chance: the covariate tests and the decision.

A candidate cause is a physical quantity that follows a covariate (``docs/diagnosis.md``): mucus, fish-belt
friction with hours post mortem; rigor, joint stiffness with hours; directional friction, friction with the
fish's slip direction; drive droop, belt speed with the load carried; adhesion, a force between fish in contact.
Each is judged where physics says the constant model predicts *no* dependence on that covariate, so that no base
model has to be right first and none can absorb the effect (the quantities: :mod:`fishfmu.analysis.observations`):

- a fish dropped alone onto a running belt lies wholly on it and slides until it moves with it; with one friction
  coefficient the time it loses beyond its fall is ``v / (2 mu g)`` whatever its age and whichever way it points:
  mucus makes it follow hours, directional friction the fish's heading;
- a fish riding alone past a photo-eye blocks it from its first to its last moment when it lies limp in the belt;
  stiff in rigor, it pivots over the step and the beam flickers: rigor makes the blocked share follow hours;
- a drive holds its speed whatever it carries unless it droops: droop makes the speed follow the load;
- touching fish part at a transfer as the constant model's do unless something holds them: adhesion makes the
  measured pairs part less than the same runs' pairs re-simulated.

Each test (:func:`covariate_test`) compares, on runs held out one at a time, the constant (refitted on the other
runs beside the candidate: one level and the nuisance terms, or a level per run where the covariate varies within
runs) with the constant plus the covariate's term; the *held-out gain* is the share of the held-out error the term
removes.  The *p-value* is the chance of a term explaining at least as much of the data (fitted on all of it) if
the quantity did not follow the covariate: the same fit on data where the covariate was shuffled where the null
makes it exchangeable (hours between fish, headings between the fish of a run, the load in time by circular
shifts, measured and modelled pairs within a run).  The p-value controls the false-positive rate (:data:`ALPHA`);
the gain says the term carries over to runs it was not fitted on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.observations import drive_rows, drop_rows, pair_rows, passage_rows

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


def _explained(d: Design, shapes: np.ndarray) -> float:
    """Share of the constant model's squared error that the best shape's term removes, fitted on all rows: the
    test statistic (the most powerful of a term's own fit; what it does on held-out runs is reported beside)."""
    y = _centre(d.y, d.group) if d.within else d.y.astype(float)
    s = _centre(shapes, d.group) if d.within else shapes
    nu = _centre(d.nuisance, d.group) if d.within else d.nuisance
    base_x = np.column_stack([np.zeros((len(y), 0)) if d.within else np.ones((len(y), 1)), nu])
    r0 = y - base_x @ _lstsq(base_x, y)
    ss0 = float(r0 @ r0)
    if ss0 <= 0.0:
        return 0.0
    best = 0.0
    for k in range(s.shape[1]):
        # the shape's part not explained by the base: regress the base's residual on it
        sk = s[:, k] - base_x @ _lstsq(base_x, s[:, k])
        den = float(sk @ sk)
        if den <= 1e-300:
            continue
        b = float(sk @ r0) / den
        if d.sign and np.sign(b) == -d.sign:
            continue
        best = max(best, b * b * den / ss0)
    return best


def _shuffled(d: Design, rng: np.random.Generator, shuffle: str) -> np.ndarray:
    """The shapes under the null: hours shuffled between runs, headings within runs, loads shifted in time."""
    groups = np.unique(d.group)
    if shuffle == "between":
        perm = rng.permutation(len(groups))
        # the run -> covariate map permuted: each run takes another run's shape values (one value per run)
        first = {g: np.flatnonzero(d.group == g)[0] for g in groups}
        out = np.empty_like(d.shapes)
        for g, h in zip(groups, groups[perm]):
            out[d.group == g] = d.shapes[first[h]]
        return out
    if shuffle == "rows":  # every row takes another row's covariate: no run-level effect of any kind
        return d.shapes[rng.permutation(len(d.shapes))]
    out = d.shapes.copy()
    for g in groups:
        idx = np.flatnonzero(d.group == g)
        if shuffle == "within":
            out[idx] = d.shapes[rng.permutation(idx)]
        else:  # "shift": circular shift in time (rows are in time order within a group)
            out[idx] = np.roll(d.shapes[idx], int(rng.integers(1, max(len(idx), 2))), axis=0)
    return out


def covariate_test(candidate: str, quantity: str, covariate: str, d: Design, shuffle: str,
                   rng: np.random.Generator, permutations: int = PERMUTATIONS) -> CovariateTest:
    groups = np.unique(d.group)
    out = CovariateTest(candidate, quantity, covariate, len(d.y), len(groups))
    if len(groups) < 3 or len(d.y) < 8:
        out.note = f"only {len(groups)} runs with {len(d.y)} rows of {quantity}: too few to judge"
        return out
    e0, e1, chosen = _heldout_errors(d, d.shapes)
    u = e0 - e1
    total = float(e0.sum())
    out.heldout_gain = float(u.sum() / total) if total > 0 else 0.0
    boot = []
    for _ in range(1000):
        i = rng.integers(0, len(u), len(u))
        if e0[i].sum() > 0:
            boot.append(u[i].sum() / e0[i].sum())
    out.heldout_gain_ci95 = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    out.gain_by_run = {str(g): float(v) for g, v in zip(groups, u)}
    observed = _explained(d, d.shapes)
    exceed = sum(_explained(d, _shuffled(d, rng, shuffle)) >= observed - 1e-12 for _ in range(permutations))
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


# ------------------------------------------------------------------------------------------------- candidates

def _log_hours_shapes(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Monotone shapes of hours post mortem: log-time from 1 h saturating at 8, 24 or 72 h (drying)."""
    h = np.maximum(h, 0.1)
    cols, names = [], []
    for end in (8.0, 24.0, 72.0):
        cols.append(np.clip(np.log(h) / np.log(end), 0.0, 1.0))
        names.append(f"log hours, from 1 h, level from {end:g} h")
    return np.column_stack(cols), names


def _bump_shapes(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Shapes that come and go with hours post mortem (rigor sets in, holds, resolves): a bump in log-time
    peaking at 6-36 h, narrow or wide, and a rise that does not resolve within the data."""
    lh = np.log(np.maximum(h, 0.1))
    cols, names = [], []
    for peak in (6.0, 12.0, 24.0, 36.0):
        for width in (0.7, 1.2):
            cols.append(np.exp(-((lh - np.log(peak)) / width) ** 2))
            names.append(f"bump peaking at {peak:g} h (width x{np.exp(width):.1f})")
    return np.column_stack(cols), names


def mucus_test(drops: pd.DataFrame, rng: np.random.Generator) -> CovariateTest:
    """Mucus: fish-belt friction follows hours post mortem; seen in the slip of drops alone (the belt's speed a
    nuisance term)."""
    ok = drops.dropna(subset=["hours_post_mortem"])
    shapes, names = _log_hours_shapes(ok["hours_post_mortem"].to_numpy(float))
    d = Design(_robust(ok["slip_s"].to_numpy(float)), ok["run_id"].to_numpy(), shapes, names,
               ok[["belt_speed_mps"]].to_numpy(float), within=False, sign=-1)
    return covariate_test("mucus_friction", "slip of fish dropped alone [s]",
                          "hours post mortem", d, "rows", rng)


MIN_FLICKER = 0.01
"""Rigor is named only if the beams flicker for at least 1 % of a passage more at its peak than without it: a few
ms of a passage's half second to a second, what a photo-eye input scanned every few ms can still tell from a
beam's own jitter (fish of the same batch, limp, vary by a few tenths of a percent from run to run)."""
MIN_SAG = 0.01
"""Droop is named only if it takes at least 1 % off a belt's speed over the range of load the data has on it: less
changes no gap between fish that a singulation line cares about."""


def rigor_test(passages: pd.DataFrame, rng: np.random.Generator) -> CovariateTest:
    """Rigor: joint stiffness follows hours post mortem; seen in the blocked share of photo-eye passages."""
    ok = passages.dropna(subset=["hours_post_mortem"])
    shapes, names = _bump_shapes(ok["hours_post_mortem"].to_numpy(float))
    d = Design(ok["blocked"].to_numpy(float), ok["run_id"].to_numpy(), shapes, names, np.zeros((len(ok), 0)),
               within=False, sign=-1, min_effect=MIN_FLICKER)
    return covariate_test("rigor_mortis", "blocked share of photo-eye passages of fish alone", "hours post mortem",
                          d, "rows", rng)


def directional_test(drops: pd.DataFrame, rng: np.random.Generator) -> CovariateTest:
    """Directional friction: friction follows the slip direction relative to the fish; a fish dropped head
    downstream slides tail first relative to the belt, one head upstream head first."""
    ok = drops.dropna(subset=["heading"])
    d = Design(_robust(ok["slip_s"].to_numpy(float)), ok["run_id"].to_numpy(),
               ok[["heading"]].to_numpy(float), ["cos(heading at the drop)"], np.zeros((len(ok), 0)), within=True,
               sign=-1)
    return covariate_test("directional_friction", "slip of fish dropped alone [s]",
                          "heading relative to the belt's motion", d, "within", rng)


def droop_test(drive: pd.DataFrame, rng: np.random.Generator) -> CovariateTest:
    """Drive droop: belt speed follows the load carried; the sag below the setpoint against the mass on the belt
    (bed friction grows with the weight carried) or the force with which the belt brings fish up to its speed
    (creep on the drum under the force it transmits), one level per run and conveyor (an encoder's or a drive's
    offset is no droop)."""
    ok = drive.sort_values(["run_id", "conveyor_id", "t_s"])
    group = (ok["run_id"] + "/" + ok["conveyor_id"]).to_numpy()
    d = Design(ok["sag"].to_numpy(float), group, ok[["load_kg", "load_force_n"]].to_numpy(float),
               ["mass on the belt [kg]", "force bringing fish up to speed [N]"], np.zeros((len(ok), 0)), within=True,
               sign=+1, min_effect=MIN_SAG)
    return covariate_test("drive_droop", "belt speed's sag below its setpoint [share]", "the load on the belt", d,
                          "shift", rng)


def adhesion_test(pairs: pd.DataFrame, model_pairs: pd.DataFrame | None, rng: np.random.Generator) -> CovariateTest:
    """Adhesion: a force between fish in contact. Touching pairs of the measured runs against the touching pairs of
    the same runs re-simulated with the constant model (no force between fish beyond contact and friction): with
    adhesion the measured ones part less. Compared within each run, by rank (a pair held together and one that
    parted differ by rank, not by how far the parted one went); whether a pair is measured or modelled is
    shuffled among the run's pairs."""
    quantity = "rank within its run of the share of the belts' speed difference a touching pair's separation gained"
    if model_pairs is None:
        out = CovariateTest("adhesion", quantity, "contact between the fish (measured against the model)", 0, 0)
        out.note = "no re-simulation of the runs to compare the pairs with"
        return out
    both = pd.concat([pairs.assign(measured=1.0), model_pairs.assign(measured=0.0)], ignore_index=True)
    both = both[(both["touching"] == 1.0) & both["run_id"].isin(set(pairs["run_id"]) & set(model_pairs["run_id"]))]
    both = both.sort_values(["run_id", "measured"], kind="stable")
    rank = both.groupby("run_id")["growth"].rank(pct=True).to_numpy(float)
    d = Design(rank, both["run_id"].to_numpy(), both[["measured"]].to_numpy(float), ["measured (1) or modelled (0)"],
               np.zeros((len(both), 0)), within=True, sign=-1)
    return covariate_test("adhesion", quantity, "contact between the fish (measured against the model)", d, "within",
                          rng)


def _robust(y: np.ndarray) -> np.ndarray:
    """Clip a response to its median +- 3 scaled MADs: one tracker glitch or a drop that bounced must not decide a
    test."""
    med = float(np.median(y))
    mad = 1.4826 * float(np.median(np.abs(y - med))) or float(np.std(y)) or 1.0
    return np.clip(y, med - 3 * mad, med + 3 * mad)


# ------------------------------------------------------------------------------------------------- the decision

ALPHA = 0.02
"""A candidate is named only if the chance of its signature under no effect (its p-value) is at most this: with
five candidates, at most about one dataset in ten without an effect is named as one (measured on the
benchmark of independent datasets, ``docs/diagnosis.md``)."""
SUGGESTIVE = 0.10
"""A p-value above :data:`ALPHA` up to this is reported as undecided (what more runs would decide), not as none."""

WHAT_DECIDES = {
    "mucus_friction": "more runs of fish dropped one at a time onto the infeed, at more ages post mortem (fresh "
                      "batches, under 8 h, most of all)",
    "rigor_mortis": "more runs at ages between 4 and 48 h post mortem with fish riding alone past the photo-eyes",
    "directional_friction": "more fish dropped alone onto the infeed, both head downstream and head upstream",
    "drive_droop": "drive logs of runs whose belts carry varying loads (batches dumped onto the infeed)",
    "adhesion": "more batches dumped onto the infeed, with fish side by side both touching and with a gap",
}


@dataclass
class Judgement:
    """The covariate tests of every candidate and the cause they name."""

    tests: list[CovariateTest]
    cause: str
    """The named candidate, or ``none``."""
    undecided: list[str] = field(default_factory=list)
    """Candidates these runs cannot decide (not judged, or suggestive), each with what would decide it."""
    rows: dict[str, pd.DataFrame] = field(default_factory=dict, repr=False)
    """What the tests read: ``drops``, ``passages``, ``drive``, ``pairs`` and ``model_pairs`` (for plots)."""

    @property
    def decision(self) -> str:
        if self.cause != "none":
            t = next(t for t in self.tests if t.candidate == self.cause)
            return (f"{self.cause}: {t.quantity} follows {t.covariate} (p = {t.p_value:.3f}, held-out gain "
                    f"{t.heldout_gain:.1%})")
        return "none" + (f"; cannot decide {', '.join(self.undecided)}" if self.undecided else "")


def significant(t: CovariateTest) -> bool:
    """Named only when unlikely by chance and better than the constant on held-out runs."""
    return bool(t.judged and t.p_value <= ALPHA and t.heldout_gain > 0.0 and t.effect >= t.min_effect)


def judge(dataset: Dataset, rng: np.random.Generator, model: Dataset | None = None) -> Judgement:
    """Every candidate's covariate test, and the cause: of the significant candidates the one least likely by
    chance (ties, at the permutations' resolution: the larger lower end of the held-out gain's interval); none
    significant: ``none``. ``model``: the runs re-simulated with the constant (calibrated) model, in the
    measured-data format, for adhesion (the other tests read the measured data alone)."""
    rows = {"drops": drop_rows(dataset), "passages": passage_rows(dataset), "drive": drive_rows(dataset),
            "pairs": pair_rows(dataset)}
    if model is not None:
        rows["model_pairs"] = pair_rows(model)
    tests = [mucus_test(rows["drops"], rng), rigor_test(rows["passages"], rng), directional_test(rows["drops"], rng),
             droop_test(rows["drive"], rng), adhesion_test(rows["pairs"], rows.get("model_pairs"), rng)]
    named = [t for t in tests if significant(t)]
    cause = min(named, key=lambda t: (t.p_value, -t.heldout_gain_ci95[0])).candidate if named else "none"
    undecided = []
    for t in tests:
        if not t.judged:
            undecided.append(f"{t.candidate} ({t.note}; {WHAT_DECIDES[t.candidate]} would decide)")
        elif cause == "none" and not significant(t) and t.p_value <= SUGGESTIVE and t.effect >= t.min_effect:
            undecided.append(f"{t.candidate} (p = {t.p_value:.3f}; {WHAT_DECIDES[t.candidate]} would decide)")
    return Judgement(tests, cause, undecided, rows)
