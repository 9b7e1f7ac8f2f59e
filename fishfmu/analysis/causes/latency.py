"""Photo-eye latency: a sensor at fault, the photo-eyes reporting their edges late (a slow input card, an input filter,
a long scan cycle), which the plant's data would otherwise show as fish arriving late.

Signature: how far past the beam a fish riding alone had its head, by its track, when an eye reported the edge on
(:func:`fishfmu.analysis.observations.edge_rows`, ``offset_m``).  A latency is a time: the fish travels on while the
edge is on its way, so the offset grows with the fish's speed.  Where the blocked part of its outline begins behind
its tip (shape, heading, length) is a distance, the same at any speed; so the constant model predicts no dependence
on the speed.  One level per photo-eye, and per eye a term in the fish's heading and length, as nuisance; the speed
shuffled among the passages at each eye (eyes sit at belts of different speeds); sign +1 (late).  The latency is
relative to the tracks' clock: a tracker whose timestamps are early by as much gives the same data.
Extension: the latency [s], the slope fitted from the rows (no simulation); the scenario's photo-eyes carry it as
``latency_s`` (the plant reports a beam's edges that much late), and a re-simulation's edges take it
(:func:`delay_edges`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test, robust
from fishfmu.analysis.extension_fit import CandidateFit, FitContext
from fishfmu.analysis.fitting import folds, heldout_score
from fishfmu.analysis.observations import edge_rows

MIN_LATENCY_S = 0.01
"""Latency is named only if the edges come at least 10 ms late: a controller scans its inputs every 1 to 10 ms, so an
edge reaches its logic up to one scan late on every healthy line (half a scan on average), and a photo-eye's own
response takes about a millisecond; a full scan of the slowest common cycle is where a delay becomes a fault of the
line's sensing (and it still moves a fish at 1 m/s by only a centimetre).  A plant recording its beams once a
communication step has half a step of this too (5 ms at 10 ms steps)."""
BOUNDS_S = (0.0, 0.5)
BOOTSTRAP = 200


def apply(eye: dict[str, float], latency_s: float) -> None:
    """Writes the latency into a photo-eye's parameters (a table of ``[[line.photoeyes]]``)."""
    eye["latency_s"] = latency_s


def delay_edges(photoeyes: pd.DataFrame, latency_s: float) -> pd.DataFrame:
    """A photoeyes table (``sensor_id``, ``t_on_s``, ``t_off_s``) as eyes ``latency_s`` late report it: every edge,
    on and off, that much later (what the extension does to a re-simulation's edges; the physics is unchanged)."""
    return photoeyes.assign(t_on_s=photoeyes["t_on_s"] + latency_s, t_off_s=photoeyes["t_off_s"] + latency_s)


def design(rows: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(offset [m] clipped per eye (:func:`robust`), run, speed [m/s], nuisance columns, eye) of the rows with all
    they need: per eye a level (the first eye's is the intercept), and terms in heading and length (centred)."""
    ok = rows.dropna(subset=["offset_m", "speed_mps", "heading", "length_m"])
    eye = ok["sensor_id"].to_numpy()
    y = ok["offset_m"].to_numpy(float).copy()
    heading, length = ok["heading"].to_numpy(float), ok["length_m"].to_numpy(float)
    length = length - (length.mean() if len(length) else 0.0)
    cols = []
    for i, s in enumerate(np.unique(eye)):
        m = eye == s
        y[m] = robust(y[m])
        cols += ([m.astype(float)] if i else []) + [m * heading, m * length]
    nuisance = np.column_stack(cols) if cols else np.zeros((len(ok), 0))
    return y, ok["run_id"].to_numpy(), ok["speed_mps"].to_numpy(float), nuisance, eye


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """How far past the beam a fish's head was at a photo-eye's edge on, against its speed there."""
    y, run, speed, nuisance, eye = design(rows["edges"])
    d = Design(y, run, speed[:, None], ["fish speed at the edge on [m/s]"], nuisance, within=False, sign=+1,
               min_effect=MIN_LATENCY_S * float(np.ptp(speed)) if len(speed) else 0.0, strata=eye)
    return covariate_test("photoeye_latency", "how far past a photo-eye the fish's head was at its edge on [m]",
                          "the fish's speed", d, "rows", rng)


def _slope(y: np.ndarray, speed: np.ndarray, nuisance: np.ndarray) -> tuple[float, np.ndarray]:
    """(latency [s] within the bounds, the nuisance's coefficients with it) by least squares."""
    x = np.column_stack([np.ones(len(y)), nuisance, speed])
    b = np.linalg.lstsq(x, y, rcond=None)[0]
    lat = float(np.clip(b[-1], *BOUNDS_S))
    base = np.column_stack([np.ones(len(y)), nuisance])
    return lat, np.linalg.lstsq(base, y - lat * speed, rcond=None)[0]


def fit(cand: Candidate, ctx: FitContext) -> CandidateFit:
    """The latency from the measured edges (no simulation): the slope of the offset on the speed, with the eyes'
    levels and shape terms, on all runs, with a bootstrap over runs; held out by folds of runs, the offsets
    predicted without it (levels and shape terms fitted on the other runs) against with it."""
    out = CandidateFit(cand.name, error_unit="m")
    y, run, speed, nuisance, _ = design(edge_rows(ctx.dataset))
    runs = sorted(set(run))
    if len(runs) < 2:
        return out
    base_x = np.column_stack([np.ones(len(y)), nuisance])
    u, e0 = np.zeros(len(runs)), np.zeros(len(runs))
    for fold in folds(runs):
        test_rows = np.isin(run, fold)
        b0 = np.linalg.lstsq(base_x[~test_rows], y[~test_rows], rcond=None)[0]
        lat, b1 = _slope(y[~test_rows], speed[~test_rows], nuisance[~test_rows])
        for j, r in enumerate(runs):
            if r in fold:
                m = run == r
                e0[j] = float(np.sum((y[m] - base_x[m] @ b0) ** 2))
                u[j] = e0[j] - float(np.sum((y[m] - base_x[m] @ b1 - lat * speed[m]) ** 2))
    out.score(heldout_score(runs, u, e0, len(y), ctx.rng))
    out.values["latency_s"] = _slope(y, speed, nuisance)[0]
    by_run = {r: np.flatnonzero(run == r) for r in runs}
    boot = []
    for _ in range(BOOTSTRAP):
        i = np.concatenate([by_run[runs[k]] for k in ctx.rng.integers(0, len(runs), len(runs))])
        boot.append(_slope(y[i], speed[i], nuisance[i])[0])
    out.ci95["latency_s"] = (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))
    return out


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """The latency itself: a time is its own physical term."""
    return {"latency_s": float(values["latency_s"])} if "latency_s" in values else {}


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: where the head was at the edge on against the fish's speed, per eye."""
    edges = rows.get("edges")
    if edges is not None and len(edges):
        for eye, g in edges.groupby("sensor_id"):
            ax.plot(g["speed_mps"], 1e3 * g["offset_m"], ".", alpha=0.5, label=str(eye))
        ax.legend(fontsize=7)
    ax.set(xlabel="the fish's speed at the edge [m/s]", ylabel="head past the beam at the edge on [mm]")


CANDIDATE = Candidate(
    "photoeye_latency", "photo-eyes reporting their edges late (a slow input card or an input filter): the delay of "
    "every edge, on and off", ("latency_s",), "s", 0.0, (), BOUNDS_S, "sensor", apply, ("latency_s",), test=test,
    decides="runs with fish riding alone past the photo-eyes at belt speeds that differ from run to run",
    fit=fit, terms=terms, primary="latency_s", edges=delay_edges, explains=(("edges", "belt_speed_mps"),), plot=plot)
