"""The unexplained-discrepancy scan: what the data follow that no named cause explains, where, and how much.

``diagnose`` names a cause only from its list (:data:`fishfmu.analysis.candidates.CANDIDATES`).  A line may hold an
effect outside it (a slippery zone on one belt, guides wearing along the line), or a candidate may be switched off;
then "no cause" must not read as "the model fits".  The scan runs the candidates' own covariate test
(:func:`fishfmu.analysis.covariates.covariate_test`: the term beside a constant, held out run by run, its p-value
from shuffling the covariate) over every **quantity** the data carry, at every **location** it is read at, against
every **covariate** it carries:

- quantities and locations (:data:`QUANTITIES`): the slip of fish dropped alone (the infeed), the lag of fish alone
  across each transfer against the calibrated model, the blocked share of each photo-eye's passages, each drive's
  sag below its setpoint, the growth of pairs' separation at each transfer;
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

from plant.contract.measured import Dataset

from fishfmu.analysis.covariates import CovariateTest, Design, bump_shapes, covariate_test, log_hours_shapes, robust
from fishfmu.analysis.residuals import RunResiduals, alone

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


@dataclass(frozen=True)
class Covariate:
    key: str
    text: str
    column: str
    shapes: Callable[[np.ndarray], tuple[np.ndarray, list[str]]]
    varies: str
    """``runs``: one value per run (hours of a batch, a belt's speed): shuffled between runs, one level for all;
    ``fish``: varies among the rows of a run: shuffled within runs, each run its own level; ``time``: a time series
    within a run (a belt's load): shifted in time."""


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


COVARIATES: dict[str, Covariate] = {c.key: c for c in (
    Covariate("hours_post_mortem", "hours post mortem", "hours_post_mortem", _hours, "runs"),
    Covariate("weight_kg", "the fish's weight", "weight_kg", _linear("weight [kg]"), "fish"),
    Covariate("length_m", "the fish's length", "length_m", _linear("length [m]"), "fish"),
    Covariate("heading", "the fish's heading (cos of its yaw: +1 head downstream)", "heading", _linear("heading"),
              "fish"),
    Covariate("t_in_run_s", "when in the run the fish came (its drop time)", "t_in_run_s", _linear("time [s]"),
              "fish"),
    Covariate("belt_speed_mps", "the belt's speed in the run", "belt_speed_mps", _linear("belt speed [m/s]"), "runs"),
    Covariate("load_kg", "the mass on the belt", "load_kg", _linear("load [kg]"), "time"),
    Covariate("touching", "contact (between the fish of a pair; with a guide)", "touching",
              _linear("touching (1) or not (0)"), "fish"),
)}

QUANTITIES: tuple[Quantity, ...] = (
    # 5 ms of slip: a fifth of a sample of a 25 Hz tracker, averaged over a run's drops; what a friction change of a
    # tenth makes on a 0.25 m/s infeed (v / (2 mu g) = 28 ms at mu 0.45)
    Quantity("drops", "slip_s", "slip of fish dropped alone", "s", "drop", "conveyor_id", 0.005, ("belt_speed_mps",)),
    # 5 mm: about the tracker's noise, and a twentieth of a fish's body height
    Quantity("transfers", "lag_m", "lag of fish alone across the transfer (model minus measured)", "m", "transfer",
             "conveyor_id", 0.005, against_model=True),
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
    # a tenth of the belts' speed difference: what tracking noise makes of a pair's separation over 1.5 s
    Quantity("pairs", "growth", "share of the belts' speed difference a side-by-side pair's separation gained", "",
             "pairs", "conveyor_id", 0.1),
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

    def as_dict(self) -> dict:
        t = self.test
        return {"quantity": self.quantity, "location": {"kind": self.location_kind, "id": self.location_id},
                "covariate": self.covariate, "covariate_key": self.covariate_key, "shape": t.shape,
                "slope": t.slope, "effect": t.effect, "unit": self.unit, "p_value": t.p_value,
                "heldout_gain": t.heldout_gain, "heldout_gain_ci95": list(t.heldout_gain_ci95), "runs": self.runs}

    @property
    def text(self) -> str:
        t = self.test
        unit = f" {self.unit}" if self.unit else ""
        where = "every " + self.location_kind if self.location_id == "all" else f"{self.location_kind} {self.location_id}"
        return (f"{self.quantity} at {where} follows {self.covariate} ({t.shape}): "
                f"{t.effect:.3g}{unit} over the data's range (slope {t.slope:+.3g}), p = {t.p_value:.4f}, held-out "
                f"gain {t.heldout_gain:.1%}; shown most by {', '.join(self.runs) or 'no single run'}")


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
    """What it read (:func:`scan_tables`), for plots."""


# ------------------------------------------------------------------------------------------------- the tables

def _fish_table(dataset: Dataset) -> pd.DataFrame:
    frames = [r.fish.assign(run_id=r.id) for r in dataset.runs]
    f = pd.concat(frames, ignore_index=True)
    return f[["run_id", "fish_id", "weight_kg", "length_m", "drop_t_s"]].rename(columns={"drop_t_s": "t_in_run_s"})


def _belt_speeds(dataset: Dataset) -> pd.DataFrame:
    rows = [{"run_id": r.id, "conveyor_id": c, "belt_speed_mps": float(g["speed_mps"].median())}
            for r in dataset.runs if len(r.belts) for c, g in r.belts.groupby("conveyor_id")]
    return pd.DataFrame(rows, columns=["run_id", "conveyor_id", "belt_speed_mps"])


def scan_tables(dataset: Dataset, rows: dict[str, pd.DataFrame], after: list[RunResiduals]) -> dict[str, pd.DataFrame]:
    """The scan's tables: the judge's rows (measured data) with each fish's weight, length and arrival, and the lags
    of fish alone across transfers against the calibrated model (``after``)."""
    fish = _fish_table(dataset)
    speeds = _belt_speeds(dataset)
    out: dict[str, pd.DataFrame] = {}
    drops = rows.get("drops")
    if drops is not None and len(drops):
        drops = drops.drop(columns=[c for c in ("weight_kg", "length_m", "t_in_run_s") if c in drops.columns])
        out["drops"] = drops.merge(fish, on=["run_id", "fish_id"], how="left").assign(
            conveyor_id=dataset.line.conveyors[0].id)
    for name in ("edges", "guides"):
        if rows.get(name) is not None and len(rows[name]):
            out[name] = rows[name]
    passages = rows.get("passages")
    if passages is not None and len(passages):
        out["passages"] = passages.merge(fish, on=["run_id", "fish_id"], how="left")
    if rows.get("drive") is not None and len(rows["drive"]):
        out["drive"] = rows["drive"]
    if rows.get("pairs") is not None and len(rows["pairs"]):
        out["pairs"] = rows["pairs"]
    lags = [alone(b.rows).assign(run_id=b.run_id) for b in after if not b.error and len(b.rows)]
    if lags:
        t = pd.concat(lags, ignore_index=True)
        t = t[t["belt"] > 0].drop(columns=["length_m"], errors="ignore")
        t = t.merge(fish, on=["run_id", "fish_id"], how="left").merge(speeds, on=["run_id", "conveyor_id"], how="left")
        out["transfers"] = t
    return out


# ------------------------------------------------------------------------------------------------- the scan

SIZE_COVARIATES = ("weight_kg", "length_m")
GIVEN_COVARIATES = (*SIZE_COVARIATES, "heading")
"""What the model takes of every fish from the data: its weight, its length and the heading it was dropped with."""


def is_base_mismatch(q: Quantity, covariate_key: str, location_id: str) -> bool:
    """Whether a dependence is the base model's own mismatch (not uniform over fish), reported as such
    (:attr:`Scan.mismatch_findings`), never as a cause or an unexplained effect:

    - on the fish's size, anywhere: the model is given each fish's size, so a quantity following it is the model's
      response to size being wrong (the drops and passages are read as measured; what the model predicts of size
      is the part this stands in for);
    - on anything else the model is given of each fish (its heading), in a quantity read against the model, at every
      location alike: the model responds to it differently everywhere, as a property of the model. An effect that
      acts at one place (a slippery zone, a worn guide) shows at that location, and is judged there; one that acts
      through the heading on the line's physics (friction by direction) shows in the drops, read as measured."""
    if covariate_key in SIZE_COVARIATES:
        return True
    return q.against_model and location_id == "all" and covariate_key in GIVEN_COVARIATES


def _design(q: Quantity, cov: Covariate, t: pd.DataFrame, pooled: bool) -> tuple[Design, str] | None:
    cols = [q.column, cov.column, *q.nuisance]
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
    if cov.varies == "runs":  # hours of a batch, a belt's speed: shuffled between rows as the candidates do
        if len(np.unique(x)) < 3:
            return None
        shuffle, group, within = "rows", runs, False
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
        shapes = np.column_stack([shapes] + [shapes * (loc == v)[:, None] for v in places])
        names = names + [f"{n} at {v}" for v in places for n in names]
    nuisance = [t[list(q.nuisance)].to_numpy(float)] if q.nuisance else []
    if pooled and not within:  # each location its own level
        nuisance += [(loc == v).astype(float)[:, None] for v in places[1:]]
    nu = np.column_stack(nuisance) if nuisance else np.zeros((len(t), 0))
    y = t[q.column].to_numpy(float).copy()
    for v in places:  # a tracker's glitch clipped at its own location: a dependence at one is no outlier of all
        y[loc == v] = robust(y[loc == v])
    d = Design(y, group, shapes, names, nu, within=within, min_effect=q.min_effect)
    return d, shuffle


def _test(name: str, q: Quantity, cov: Covariate, d: Design, shuffle: str, rng: np.random.Generator,
          deciding: bool) -> CovariateTest:
    t = covariate_test(name, q.text, cov.text, d, shuffle, rng, permutations=FIRST_PERMUTATIONS)
    if deciding and t.judged and t.p_value <= 2.0 / (1 + FIRST_PERMUTATIONS) and t.effect >= t.min_effect:
        t = covariate_test(name, q.text, cov.text, d, shuffle, rng, permutations=FINAL_PERMUTATIONS)
    return t


def scan(tables: dict[str, pd.DataFrame], rng: np.random.Generator, explained: set[tuple[str, str]],
         alpha: float) -> Scan:
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
            if (q.table, cov.key) in explained or cov.column not in t.columns or cov.column in q.nuisance:
                continue
            made = _design(q, cov, t, pooled=True)
            if made is not None:
                plans.append((q, cov, t, *made))
    threshold = alpha / max(len(plans), 1)
    tests, findings, mismatch = [], [], []
    for q, cov, t, d, shuffle in plans:
        test = _test(f"scan:{q.table}~{cov.key}", q, cov, d, shuffle, rng, deciding=True)
        tests.append((q, "all", cov.key, test))
        if not (test.judged and test.p_value <= threshold and test.heldout_gain > 0.0 and test.effect >= test.min_effect):
            continue
        place = test.shape.rsplit(" at ", 1)[1] if " at " in test.shape else "all"
        shown = sorted(((g, r) for r, g in test.gain_by_run.items() if g > 0), reverse=True)[:3]
        f = Finding(q.text, q.unit, q.location_kind, place, cov.text, cov.key, test, [r for _, r in shown], q.table)
        (mismatch if is_base_mismatch(q, cov.key, place) else findings).append(f)
    findings.sort(key=lambda f: (f.test.p_value, -f.test.heldout_gain))
    return Scan(findings, tests, threshold, mismatch, tables)


# ------------------------------------------------------------------------------------------------- how well it fits

def tracker_noise_m(dataset: Dataset) -> float:
    """The tracker's own noise along the line [m], from the measured tracks alone: the second differences of a fish's
    position at evenly spaced samples (a steadily moving fish's are noise, sqrt(6) sigma), robust to the
    accelerations at drops and transfers (median absolute deviation)."""
    d2 = []
    for run in dataset.runs:
        for _, tr in run.tracks.groupby("fish_id", sort=False):
            t, x = tr["t_s"].to_numpy(float), tr["x_m"].to_numpy(float)
            if len(t) < 5:
                continue
            dt = np.diff(t)
            even = np.abs(dt[1:] - dt[:-1]) <= 0.1 * dt[:-1]
            d2.append((x[2:] - 2 * x[1:-1] + x[:-2])[even])
    if not d2:
        return float("nan")
    a = np.concatenate(d2)
    return float(1.4826 * np.median(np.abs(a - np.median(a))) / np.sqrt(6.0))


def base_mismatch(tables: dict[str, pd.DataFrame], rng: np.random.Generator, n_boot: int = 1000) -> dict:
    """What the calibrated model gets wrong the same way for every fish: each transfer's mean lag (model minus
    measured, fish alone) with a 95 % interval from resampling runs."""
    t = tables.get("transfers")
    out: dict[str, dict] = {}
    if t is None or not len(t):
        return out
    for loc, rows in t.groupby("conveyor_id", sort=True):
        per_run = rows.groupby("run_id")["lag_m"].agg(["sum", "count"])
        s, n = per_run["sum"].to_numpy(float), per_run["count"].to_numpy(float)
        idx = rng.integers(0, len(s), size=(n_boot, len(s)))
        boot = s[idx].sum(axis=1) / np.maximum(n[idx].sum(axis=1), 1)
        out[str(loc)] = {"mean_lag_m": float(s.sum() / n.sum()), "ci95_m": [float(np.percentile(boot, 2.5)),
                                                                            float(np.percentile(boot, 97.5))],
                         "fish": int(n.sum()), "runs": int(len(s))}
    return out


def fit_quality(tables: dict[str, pd.DataFrame], noise_m: float) -> dict:
    """How well the model fits the lags of fish alone across transfers, beyond each transfer's constant: their RMS
    against what the tracker's noise alone makes of a lag (a difference of two medians of ``n_samples`` samples
    each: 1.25 sigma / sqrt(n) apiece)."""
    t = tables.get("transfers")
    if t is None or not len(t) or not np.isfinite(noise_m):
        return {}
    centred = t["lag_m"] - t.groupby("conveyor_id")["lag_m"].transform("mean")
    n = t["n_samples"].clip(lower=1).to_numpy(float) if "n_samples" in t.columns else np.full(len(t), 10.0)
    expected = float(np.sqrt(np.mean(2.0 * (1.2533 * noise_m) ** 2 / n)))
    rms = float(np.sqrt(np.mean(centred.to_numpy(float) ** 2)))
    return {"lag_rms_m": rms, "tracker_noise_m": noise_m, "noise_lag_rms_m": expected,
            "ratio": rms / expected if expected > 0 else float("nan"), "fish_transfers": int(len(t))}
