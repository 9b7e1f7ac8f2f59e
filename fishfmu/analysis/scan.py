"""The unexplained-discrepancy scan: what the data follow that no named cause explains, where, and how much.

``diagnose`` names a cause only from its list (:data:`fishfmu.analysis.candidates.CANDIDATES`).  A line may hold an
effect outside it (a slippery zone on one belt, guides wearing along the line), or a candidate may be switched off;
then "no cause" must not read as "the model fits".  The scan runs the candidates' own covariate test
(:func:`fishfmu.analysis.covariates.covariate_test`: the term beside a constant, held out run by run, its p-value
from shuffling the covariate) over every **quantity** the data carry, at every **location** it is read at, against
every **covariate** it carries:

- quantities and locations (:data:`QUANTITIES`): the slip of fish dropped alone (the infeed), the lag of fish alone
  across each transfer against the calibrated model, the blocked share of each photo-eye's passages, each drive's
  sag below its setpoint, the growth of touching pairs' separation at the transfers against the model's;
- covariates (:data:`COVARIATES`): hours post mortem, the fish's weight, length and heading, when in the run it came,
  the belt's speed, the load on a belt, contact between fish.

A location's own constant is fitted beside every term (within each run where the covariate varies inside runs), so
what the model gets wrong the same way for every fish, run and age (the base model's own mismatch, reported once by
:func:`base_mismatch`) is never a finding; a finding is a *dependence* beyond it.  The quantity-covariate pairs a
named cause accounts for (:attr:`~fishfmu.analysis.candidate.Candidate.explains`) are left out: the named cause's
term stands for them (a linear stand-in for re-simulating the extended model).  Many tests are run, so each is
held to ``ALPHA / number of tests`` (Bonferroni): over a dataset without any effect the scan reports something with
a chance of at most ``ALPHA``, as a candidate is named.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from fishfmu.analysis.covariates import (CovariateTest, Design, against_model, bump_shapes, covariate_test,
                                         each_shape_alone, log_hours_shapes, robust, run_clustered_test)

FIRST_PERMUTATIONS = 199
"""Shuffles per test first; a test whose p-value could still reach the threshold is shuffled more."""
FINAL_PERMUTATIONS = 4999
"""Shuffles of a test that might be a finding: p-values resolve to 2e-4, below ALPHA / a hundred tests."""


@dataclass(frozen=True)
class Quantity:
    """A quantity the scan reads: a table of rows (one per observation), its column, where it is read."""

    table: str
    column: str
    text: str
    unit: str
    location_kind: str
    """``drop``, ``transfer``, ``photoeye``, ``drive`` or ``pairs`` (``diagnosis.json``'s location kinds)."""
    location_column: str
    min_effect: float
    """The smallest dependence worth reporting, in ``unit`` over the covariate's range in the data."""
    nuisance: tuple[str, ...] = ()
    against_model: bool = False
    """Read as the measured value minus the calibrated model's (the transfers' lags), not as measured alone."""
    model_table: str = ""
    """Read against this table's rows (the same runs re-simulated with the calibrated model) by rank within each run,
    among the rows where the covariate (a 0/1 flag) is 1 (:func:`~fishfmu.analysis.covariates.against_model`): for
    rows no model row matches one to one (which pairs of a pile part is chaos)."""
    sign: int = 0
    """+1 / -1: only a dependence of this sign is a finding (:attr:`~fishfmu.analysis.covariates.Design.sign`)."""
    shared: tuple[str, ...] = ()
    """The base model's own mismatch in this quantity, the same law at every location (its response to what it is
    given: the fish's heading, the speed step at a transfer): columns fitted beside every other covariate's term, so
    that a finding is a dependence beyond it (:func:`take_up_law` reports it)."""


@dataclass(frozen=True)
class Covariate:
    key: str
    text: str
    column: str
    shapes: Callable[[np.ndarray], tuple[np.ndarray, list[str]]]
    varies: str
    """``runs``: one value per run (hours of a batch, a belt's speed): shuffled between runs, one level for all;
    ``fish``: varies among the rows of a run: shuffled within runs, each run its own level; ``time``: a time series
    within a run (a belt's load): shifted in time; ``location``: where the quantity is read (a transfer's own level,
    :func:`_level_design`)."""


def _linear(name: str) -> Callable[[np.ndarray], tuple[np.ndarray, list[str]]]:
    return lambda v: (np.asarray(v, dtype=float)[:, None], [f"linear in {name}"])


def _hours(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """A few monotone and come-and-go shapes in hours post mortem (ageing, drying, rigor): fewer than a candidate
    offers, because each is also offered at every location alone, and a shape chosen among many on some runs
    predicts a run of an age outside theirs badly."""
    a, an = log_hours_shapes(h)
    b, bn = bump_shapes(h)
    keep_a, keep_b = [1, 2], [3, 5]  # log-time levelling at 24 and 72 h; wide bumps peaking at 12 and 24 h
    return (np.column_stack([np.asarray(h, dtype=float), a[:, keep_a], b[:, keep_b]]),
            ["linear in hours"] + [an[i] for i in keep_a] + [bn[i] for i in keep_b])


def _hours_monotone(h: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Only shapes that rise or fall with age (drying, ageing), offered apart from :func:`_hours`' bumps: where a bump
    fits some runs best but predicts a run of another age badly (held out, it loses), a monotone dependence on age
    would be masked by it (a drying mucus's slip at the infeed, found with its bump losing 525 % held out)."""
    a, an = log_hours_shapes(h)
    return np.column_stack([np.asarray(h, dtype=float), a]), ["linear in hours", *an]


COVARIATES: dict[str, Covariate] = {c.key: c for c in (
    Covariate("hours_post_mortem", "hours post mortem", "hours_post_mortem", _hours, "runs"),
    Covariate("weight_kg", "the fish's weight", "weight_kg", _linear("weight [kg]"), "fish"),
    Covariate("length_m", "the fish's length", "length_m", _linear("length [m]"), "fish"),
    Covariate("heading", "the fish's heading (cos of its yaw: +1 head downstream)", "heading", _linear("heading"),
              "fish"),
    Covariate("t_in_run_s", "when in the run the fish came (its drop time)", "t_in_run_s", _linear("time [s]"),
              "fish"),
    Covariate("belt_speed_mps", "the belt's speed in the run", "belt_speed_mps", _linear("belt speed [m/s]"), "runs"),
    Covariate("speed_step_mps", "the speed step at the transfer (the belt's speed less the one before it)",
              "speed_step_mps", _linear("speed step [m/s]"), "runs"),
    Covariate("load_kg", "the mass on the belt", "load_kg", _linear("load [kg]"), "time"),
    Covariate("touching", "contact (between the fish of a pair; with a guide)", "touching",
              _linear("touching (1) or not (0)"), "fish"),
    Covariate("hours_monotone", "hours post mortem (rising or falling with age only)", "hours_post_mortem",
              _hours_monotone, "runs"),
    # not a property of a fish or a run: where it is read (shapes made in _level_design)
    Covariate("transfer", "the transfer itself, beyond the take-up law every transfer shares", "conveyor_id",
              _linear("transfer"), "location"),
)}

TAKE_UP = ("speed_step_mps", "speed_step_sq_m2ps2")
"""The take-up law's columns: the speed step at a transfer and its square."""

QUANTITIES: tuple[Quantity, ...] = (
    # 5 ms of slip: a fifth of a sample of a 25 Hz tracker, averaged over a run's drops; what a friction change of a
    # tenth makes on a 0.25 m/s infeed (v / (2 mu g) = 28 ms at mu 0.45)
    Quantity("drops", "slip_s", "slip of fish dropped alone", "s", "drop", "conveyor_id", 0.005, ("belt_speed_mps",)),
    # 5 mm: about the tracker's noise, and a twentieth of a fish's body height. Shared: the base model's own take-up
    # law (its lag rising with the speed step, the more the larger the step: a fish slides Dv^2 / (2 mu g) before it
    # rides) and its response to the heading, the same at every transfer
    Quantity("transfers", "lag_m", "lag of fish alone across the transfer (model minus measured)", "m", "transfer",
             "conveyor_id", 0.005, against_model=True, shared=("heading", *TAKE_UP)),
    # 1 % of a passage: what rigor's test takes as the smallest flicker a photo-eye input can tell
    Quantity("passages", "blocked", "blocked share of photo-eye passages of fish alone", "share", "photoeye",
             "sensor_id", 0.01),
    # 1 % of the setpoint: droop's smallest worth naming, an encoder's and a drive's own scatter
    Quantity("drive", "sag", "belt speed's sag below its setpoint", "share", "drive", "conveyor_id", 0.01),
    # 5 mm of where a fish's head is when its eye reports it: 10 ms (a controller's input scan, latency's smallest
    # worth naming) at 0.5 m/s
    # (where the head tip sits relative to the mid-point the tracker gives is the fish's heading and length: geometry,
    # nuisance terms as in latency's own test, never a finding)
    Quantity("edges", "offset_m", "how far past the beam a fish alone was when its eye reported it", "m", "photoeye",
             "sensor_id", 0.005, ("heading", "length_m")),
    # 1 cm/s of slip riding a belt: a fish held back that much is 1 cm behind after a second (guide wear's smallest).
    # Not against the position along the belt: measured alone, slip falls along every belt as fish are taken up to
    # its speed, which the model predicts as well (guide wear's own test takes the stretch's level out)
    Quantity("guides", "slip_mps", "slip of fish riding a belt (its speed below the belt's)", "m/s", "belt",
             "conveyor_id", 0.01),
    # how much of the belts' speed difference a side-by-side pair's separation gained, the touching pairs against the
    # calibrated model's touching pairs of the same runs (not against the measured pairs with a gap: touching fish
    # part less readily than fish apart in any physics; the model's response is the reference, as for the lags).
    # One-sided, held together more than the model: what touching fish on a line share that the model lacks holds
    # them (slime, scales, blood, skin drying sticky); nothing on a line makes touching fish repel. The other
    # direction is the model's own fish-fish contact: our fish part less readily than the independent simulator's on
    # all of its no-effect datasets (docs/diagnosis.md). 5 points of rank: a twentieth of a run's pairs reordered
    Quantity("pairs", "growth", "touching pairs held together more than the calibrated model's: the rank of the "
             "separation a touching pair gained within its run, among the model's touching pairs of the run", "", "pairs",
             "conveyor_id", 0.05, against_model=True, model_table="model_pairs", sign=-1),
)


@dataclass
class Finding:
    """A dependence no named cause explains: a quantity at a location follows a covariate."""

    quantity: str
    unit: str
    location_kind: str
    location_id: str
    covariate: str
    covariate_key: str
    test: CovariateTest
    runs: list[str]
    """The runs that show it most (the largest held-out gain of the term)."""
    table: str = ""
    model_table: str = ""
    """The model's rows it was read against (:attr:`Quantity.model_table`): the term is measured against modelled."""
    or_at: dict[str, float] = field(default_factory=dict)
    """A transfer's own level: the other transfers whose own level explains the lags about as well (their level),
    where the shared law cannot tell which one departs from it (:func:`_rival_levels`)."""

    def as_dict(self) -> dict:
        t = self.test
        return {"quantity": self.quantity, "location": {"kind": self.location_kind, "id": self.location_id},
                "covariate": self.covariate, "covariate_key": self.covariate_key, "shape": t.shape,
                "slope": t.slope, "effect": t.effect, "unit": self.unit, "p_value": t.p_value,
                "heldout_gain": t.heldout_gain, "heldout_gain_ci95": list(t.heldout_gain_ci95), "runs": self.runs,
                "model_table": self.model_table, "or_at": self.or_at}

    @property
    def text(self) -> str:
        t = self.test
        unit = f" {self.unit}" if self.unit else ""
        where = "every " + self.location_kind if self.location_id == "all" else f"{self.location_kind} {self.location_id}"
        shown = f"shown most by {', '.join(self.runs) or 'no single run'}"
        if self.model_table:  # the pairs' location is the transfer they cross
            where = "every transfer" if self.location_id == "all" else f"transfer {self.location_id}"
            return (f"{self.quantity}, at {where}: {t.slope:+.3g}{unit} measured against modelled, p = {t.p_value:.4f}, "
                    f"held-out gain {t.heldout_gain:.1%}; {shown}")
        if self.covariate_key == "transfer":
            rivals = ", ".join(f"{at} {level:+.3g}{unit}" for at, level in self.or_at.items())
            rivals = f" (or {rivals}: the shared law cannot tell which departs from it)" if rivals else ""
            return (f"{self.quantity} at {where}: {t.slope:+.3g}{unit} beyond the take-up law every transfer shares"
                    f"{rivals}, p = {t.p_value:.4f}, held-out gain {t.heldout_gain:.1%}; {shown}")
        return (f"{self.quantity} at {where} follows {self.covariate} ({t.shape}): "
                f"{t.effect:.3g}{unit} over the data's range (slope {t.slope:+.3g}), p = {t.p_value:.4f}, held-out "
                f"gain {t.heldout_gain:.1%}; {shown}")


@dataclass
class Scan:
    findings: list[Finding]
    tests: list[tuple[Quantity, str, str, CovariateTest]]
    """Every test run: quantity, location id, covariate key, the test."""
    threshold: float
    """The p-value a finding needs (``ALPHA`` over the number of deciding tests)."""
    mismatch_findings: list[Finding] = field(default_factory=list)
    """Dependences that are the base model's own mismatch (:func:`is_base_mismatch`), reported as such."""
    tables: dict[str, pd.DataFrame] = field(default_factory=dict, repr=False)
    """What it read (:func:`fishfmu.analysis.scan_tables.scan_tables`), for plots."""

    def results(self) -> list[dict]:
        """Every test judged, found or not (``diagnosis.json`` ``scan.results``): what fell short of the threshold,
        and by how much, is what the runs could not decide."""
        return [{"quantity": q.table, "covariate_key": key, "shape": t.shape, "p_value": t.p_value,
                 "heldout_gain": t.heldout_gain, "slope": t.slope, "effect": t.effect}
                for q, _, key, t in self.tests if t.judged]


# ------------------------------------------------------------------------------------------------- the scan

SIZE_COVARIATES = ("weight_kg", "length_m")
GIVEN_COVARIATES = (*SIZE_COVARIATES, "heading")
"""What the model takes of every fish from the data: its weight, its length and the heading it was dropped with."""
GIVEN_TO_RUNS = ("belt_speed_mps", "speed_step_mps")
"""What the model takes of every run from the data: the belts' logged speeds (replayed)."""


def is_base_mismatch(q: Quantity, covariate_key: str, location_id: str) -> bool:
    """Whether a dependence is the base model's own mismatch (not uniform over fish), reported as such
    (:attr:`Scan.mismatch_findings`), never as a cause or an unexplained effect:

    - on the fish's size, anywhere: the model is given each fish's size, so a quantity following it is the model's
      response to size being wrong (the drops and passages are read as measured; what the model predicts of size
      is the part this stands in for);
    - on anything else the model is given of each fish (its heading) or of each run (the belts' speeds), in a quantity
      read against the model, at every location alike: the model responds to it differently everywhere, as a property
      of the model. An effect that acts at one place (a slippery zone, a worn guide) shows at that location, and is
      judged there; one that acts through the heading on the line's physics (friction by direction) shows in the
      drops, read as measured."""
    if covariate_key in SIZE_COVARIATES:
        return True
    return q.against_model and location_id == "all" and covariate_key in (*GIVEN_COVARIATES, *GIVEN_TO_RUNS)


def _level_design(q: Quantity, t: pd.DataFrame) -> tuple[Design, str] | None:
    """A level of its own at one transfer, beyond the take-up law every transfer shares (a slippery zone where fish
    land on a belt: each fish slides longer there, by about ``dv^2 / (2 g)`` times the change in ``1 / mu``).

    The other tests give every location its own level, so that what the model gets wrong alike at every transfer
    is no finding; a level at one transfer would then never be one. Here the law (the speed step, its square and the
    heading; each run its own level) is one for all transfers, and each transfer's own level is offered beside it.
    It is judged by the level's spread between runs (:func:`~fishfmu.analysis.covariates.run_clustered_test`): all
    the fish of a run at a transfer share its step and whatever the law misses there, so shuffling fish among
    transfers would count them as independent evidence (on a dataset with a latency and nothing at the transfers it
    gave c4 at p 0.0002). The steps differ from run to run (each run's setpoints), so a level
    that the law's shape would take up at the transfers' mean steps is told from it by the runs' steps. With fewer
    than three transfers the law is not pinned by the others: no test."""
    law = [c for c in q.shared if c in t.columns]
    if not set(TAKE_UP) <= set(law):
        return None
    t = t.dropna(subset=[q.column, *law])
    loc = t[q.location_column].astype(str).to_numpy()
    places = np.unique(loc)
    if len(places) < 3 or len(t) < 8 or t["run_id"].nunique() < 3:
        return None
    y = t[q.column].to_numpy(float).copy()
    for v in places:
        y[loc == v] = robust(y[loc == v])
    shapes = np.column_stack([(loc == v).astype(float) for v in places])
    # one-sided: fish held back at one transfer (lag = model minus measured, above the law). What wears at a landing
    # (a polished or slimed belt, a sagging transfer) holds fish back; nothing on a line makes one transfer grip
    # better with use. And the base model's own mismatch has the first transfer's fish ahead of the law (below)
    d = Design(y, t["run_id"].astype(str).to_numpy(), shapes, [f"a level of its own at {v}" for v in places],
               t[law].to_numpy(float), within=True, sign=+1, min_effect=q.min_effect)
    return d, "within"  # judged by run_clustered_test, not by a shuffle


RIVAL_SHARE = 0.8
"""Another transfer's own level that explains at least this share of what the chosen one does is named beside it."""


def _rival_levels(d: Design, chosen: str) -> dict[str, float]:
    """The transfers other than ``chosen`` whose own level explains the lags nearly as well (each alone beside the
    law, fitted on all runs), with that level: with three transfers a law of two terms bent by one transfer's level
    can fit a neighbour's level almost as well (two-sided, a slippery landing on c3 read as c2 ahead)."""
    fits = {name.rsplit(" at ", 1)[-1]: fit for name, fit in zip(d.shape_names, each_shape_alone(d))}
    best = fits[chosen][0]
    return {at: level for at, (share, level) in fits.items() if at != chosen and share >= RIVAL_SHARE * best}


def _design(q: Quantity, cov: Covariate, t: pd.DataFrame, pooled: bool) -> tuple[Design, str] | None:
    if cov.varies == "location":
        return _level_design(q, t) if pooled else None
    # the base model's shared law beside the term: a covariate in its take-up part is tested at each location beyond
    # it; the heading is tested without it (everywhere alike it is the mismatch itself, reported as such)
    in_law = cov.column in q.shared and cov.column in TAKE_UP
    shared = [c for c in q.shared if c in t.columns and (in_law or c != cov.column)]  # without belt logs: no law
    cols = [q.column, cov.column, *q.nuisance, *shared]
    if any(c not in t.columns for c in cols):
        return None
    t = t.dropna(subset=cols)
    if len(t) < 8 or t["run_id"].nunique() < 3:
        return None
    if cov.varies == "time" and "t_s" in t.columns:
        t = t.sort_values(["run_id", q.location_column, "t_s"])
    x = t[cov.column].to_numpy(float)
    if np.ptp(x) <= 0.0:
        return None
    runs = t["run_id"].astype(str).to_numpy()
    between = in_law or cov.key == "belt_speed_mps"
    if cov.varies == "runs":  # hours of a batch, a belt's speed: one value for a run's fish (at a location)
        if len(np.unique(x)) < 3:
            return None
        # the speed step, offered at each transfer alone, is judged within runs (each its own level: what a run
        # shares at every transfer, its batch and its speeds, is not one transfer's take-up). The step and the belt's
        # speed are shuffled between runs location by location: shuffled among rows, a chance alignment of a few
        # runs counts as many fish's evidence (every belt-speed finding at one place on the benchmark's datasets had
        # a held-out gain whose interval reached below zero). The hours stay shuffled among rows, as the candidates
        # do: their bumps, offered for ten runs, fit most shuffles of runs (docs/diagnosis.md)
        shuffle, group, within = ("runs" if between else "rows"), runs, in_law
    else:  # within a run (and a location): each its own level
        shuffle = "shift" if cov.varies == "time" else "within"
        group = np.char.add(np.char.add(runs, "/"), t[q.location_column].astype(str).to_numpy()) if pooled else runs
        if not (pd.Series(x).groupby(group).nunique() > 1).any():
            return None
        within = True
    shapes, names = cov.shapes(x)
    loc = t[q.location_column].astype(str).to_numpy()
    places = np.unique(loc)
    if pooled and len(places) > 1:  # the term everywhere, or at one location only: the test takes the best
        everywhere = ([], []) if in_law else ([shapes], names)  # in the law, everywhere is the law itself
        shapes = np.column_stack(everywhere[0] + [shapes * (loc == v)[:, None] for v in places])
        names = everywhere[1] + [f"{n} at {v}" for v in places for n in names]
    elif in_law:
        return None
    nuisance = [t[list(q.nuisance) + shared].to_numpy(float)] if q.nuisance or shared else []
    if pooled and (not within or in_law):  # each location its own level
        nuisance += [(loc == v).astype(float)[:, None] for v in places[1:]]
    nu = np.column_stack(nuisance) if nuisance else np.zeros((len(t), 0))
    y = t[q.column].to_numpy(float).copy()
    for v in places:  # a tracker's glitch clipped at its own location: a dependence at one is no outlier of all
        y[loc == v] = robust(y[loc == v])
    d = Design(y, group, shapes, names, nu, within=within, min_effect=q.min_effect, strata=loc if between else None)
    return d, shuffle


def _against_model_design(q: Quantity, cov: Covariate, t: pd.DataFrame, model: pd.DataFrame | None
                          ) -> tuple[Design, str] | None:
    """The quantity's rows where the covariate holds against the model's rows where it holds
    (:attr:`Quantity.model_table`), one term for every location: the model is the reference at each."""
    if model is None or cov.column not in model.columns or not set(np.unique(t[cov.column])) <= {0.0, 1.0}:
        return None
    held = [rows[rows[cov.column] == 1.0] for rows in (t, model)]
    if min(len(h) for h in held) < 8 or held[0]["run_id"].nunique() < 3:
        return None
    return against_model(*held, q.column, sign=q.sign, min_effect=q.min_effect), "within"


def _test(name: str, q: Quantity, cov: Covariate, d: Design, shuffle: str, rng: np.random.Generator,
          deciding: bool) -> CovariateTest:
    t = covariate_test(name, q.text, cov.text, d, shuffle, rng, permutations=FIRST_PERMUTATIONS)
    if deciding and t.judged and t.p_value <= 2.0 / (1 + FIRST_PERMUTATIONS) and t.effect >= t.min_effect:
        t = covariate_test(name, q.text, cov.text, d, shuffle, rng, permutations=FINAL_PERMUTATIONS)
    return t


def _place(shape: str, locations: pd.Series) -> str:
    """The location a term's shape name is at (``... at c4``), or ``all``: only a location the rows carry counts
    (a shape's own name may say "at": "bump at 24 h")."""
    return next((v for v in map(str, locations.unique()) if shape.endswith(f" at {v}")), "all")


def explained_by(pairs: set[tuple[str, str]], table: str, covariate_key: str) -> bool:
    """Whether the (quantity, covariate) pairs of named causes (:attr:`~fishfmu.analysis.candidate.Candidate.explains`)
    stand for this covariate at this quantity: in every family of shapes it is offered in (by its column: age in
    monotone shapes as well as with rigor's bumps)."""
    return bool({(table, covariate_key), (table, COVARIATES[covariate_key].column)} & pairs)


def scan(tables: dict[str, pd.DataFrame], rng: np.random.Generator, explained: set[tuple[str, str]],
         alpha: float, levels_beside_named: bool = False) -> Scan:
    """Every quantity, its locations pooled (each its own level), against every covariate its rows carry but the
    pairs a named cause explains (``explained``: (table, covariate key)); a finding: p-value at most ``alpha`` over
    the number of these tests, a positive held-out gain and an effect worth reporting.  Where it is: each location's
    term: the covariate's shapes are offered everywhere and at each location alone, and the test takes the one that fits
    best (its p-value from the best of them under shuffling, so offering many costs what it should)."""
    plans = []
    for q in QUANTITIES:
        t = tables.get(q.table)
        if t is None or not len(t) or q.location_column not in t.columns:
            continue
        for cov in COVARIATES.values():
            if explained_by(explained, q.table, cov.key) or cov.column not in t.columns or cov.column in q.nuisance:
                continue
            if cov.varies == "location" and not levels_beside_named and any(table == q.table for table, _ in explained):
                continue  # a named cause acting on this quantity moves its levels too: its own term stands for them
            made = (_against_model_design(q, cov, t, tables.get(q.model_table)) if q.model_table
                    else _design(q, cov, t, pooled=True))
            if made is not None:
                plans.append((q, cov, t, *made))
    # tests added later draw their shuffles after the ones before them (the same draws as before they were added):
    # the transfers' own levels, then the quantities read against the model's own rows, then age's monotone shapes
    plans.sort(key=lambda plan: (plan[1].key == "hours_monotone", bool(plan[0].model_table),
                                 plan[1].varies == "location"))
    threshold = alpha / max(len(plans), 1)
    tests, findings, mismatch = [], [], []
    for q, cov, t, d, shuffle in plans:
        test = (run_clustered_test(f"scan:{q.table}~{cov.key}", q.text, cov.text, d, rng) if cov.varies == "location"
                else _test(f"scan:{q.table}~{cov.key}", q, cov, d, shuffle, rng, deciding=True))
        tests.append((q, "all", cov.key, test))
        if not (test.judged and test.p_value <= threshold and test.heldout_gain > 0.0 and test.effect >= test.min_effect):
            continue
        place = _place(test.shape, t[q.location_column])
        shown = sorted(((g, r) for r, g in test.gain_by_run.items() if g > 0), reverse=True)[:3]
        f = Finding(q.text, q.unit, q.location_kind, place, cov.text, cov.key, test, [r for _, r in shown], q.table,
                    q.model_table, _rival_levels(d, place) if cov.varies == "location" else {})
        (mismatch if is_base_mismatch(q, cov.key, place) else findings).append(f)
    # a transfer's own level where the quantity also follows a covariate there: that dependence's mean, said once
    # by the dependence, which says more
    followed = {(f.table, f.location_id) for f in findings if f.covariate_key != "transfer"}
    findings = [f for f in findings if f.covariate_key != "transfer" or (f.table, f.location_id) not in followed]
    findings.sort(key=lambda f: (f.test.p_value, -f.test.heldout_gain))
    # one covariate found in two families of shapes at one place (age, monotone and come-and-go): said once, the best
    said = set()
    for f in list(findings):
        once = (f.table, f.location_id, COVARIATES[f.covariate_key].column)
        if once in said:
            findings.remove(f)
        said.add(once)
    return Scan(findings, tests, threshold, mismatch, tables)
