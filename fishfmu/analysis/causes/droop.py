"""Drive droop: belt speed follows the load carried (belt creep on its drum, bed friction under the weight).

Signature: the drive logs' speed below the setpoint (settled, 0.5 s windows) against the mass on each belt (tracks
and the fish's weights) and the force bringing fish up to speed; a drive holds its speed whatever it carries unless
it droops (sign +1).  Extension: each drive's ``belt_slip`` and speed lost per kg carried, from the drive logs,
linear (no simulation).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Candidate, Terms
from fishfmu.analysis.covariates import CovariateTest, Design, covariate_test
from fishfmu.analysis.extension_fit import CandidateFit, FitContext
from fishfmu.analysis.fitting import folds, heldout_score

MIN_SAG = 0.01
"""Droop is named only if it takes at least 1 % off a belt's speed over the range of load the data has on it: less
changes no gap between fish that a singulation line cares about."""


def apply(drive: dict[str, float], belt_slip: float) -> None:
    drive["belt_slip"] = belt_slip


def hide(p: PlantParams, drive: dict[str, float], s: float) -> None:
    drive["belt_slip"] = 4e-4 * s


def test(rows: dict[str, pd.DataFrame], rng: np.random.Generator) -> CovariateTest:
    """The sag below the setpoint against the mass on the belt or the force with which the belt brings fish up to
    its speed, one level per run and conveyor (an encoder's or a drive's offset is no droop)."""
    ok = rows["drive"].sort_values(["run_id", "conveyor_id", "t_s"])
    group = (ok["run_id"] + "/" + ok["conveyor_id"]).to_numpy()
    d = Design(ok["sag"].to_numpy(float), group, ok[["load_kg", "load_force_n"]].to_numpy(float),
               ["mass on the belt [kg]", "force bringing fish up to speed [N]"], np.zeros((len(ok), 0)), within=True,
               sign=+1, min_effect=MIN_SAG)
    return covariate_test("drive_droop", "belt speed's sag below its setpoint [share]", "the load on the belt", d,
                          "shift", rng)


def fit(cand: Candidate, ctx: FitContext) -> CandidateFit:
    """Per conveyor's drive: the belt speed lost per newton of load force (the drive FMU's ``belt_slip``: creep on
    the drum under the force that pulls the fish along) and per kilogram of fish on the belt (bed friction that
    grows with the weight carried), fitted together by least squares with an offset.  Per drive, because a line's
    drives differ (a droop that is a share of the belt's speed is a different slip on each belt).  ``values``: each
    drive's ``belt_slip[c1]`` and ``droop_per_kg[c1]`` ..., and ``belt_slip`` (their mean over the drives)."""
    rng = ctx.rng
    out = CandidateFit(cand.name, error_unit="m/s")
    (pname,) = cand.parameters
    lo, hi = cand.bounds
    d = ctx.drive.dropna(subset=["residual_mps", "load_force_n"])
    if "load_mass_kg" not in d:
        d = d.assign(load_mass_kg=0.0)
    d = d.fillna({"load_mass_kg": 0.0})
    runs = sorted(d["run_id"].unique())
    conveyors = sorted(d["conveyor_id"].unique())
    if len(runs) < 2:
        return out

    def slopes(rows: pd.DataFrame) -> dict[str, tuple[float, float]]:
        """(speed lost per N, per kg) of each drive: least squares with an offset, a regressor without spread left out."""
        res = {}
        for c in conveyors:
            rc = rows[rows["conveyor_id"] == c]
            cols = [k for k in ("load_force_n", "load_mass_kg") if len(rc) >= 4 and np.std(rc[k]) > 1e-9]
            coef = dict.fromkeys(("load_force_n", "load_mass_kg"), 0.0)
            if cols:
                a = np.column_stack([np.ones(len(rc))] + [rc[k].to_numpy(float) for k in cols])
                sol = np.linalg.lstsq(a, rc["residual_mps"].to_numpy(float), rcond=None)[0]
                coef.update({k: -float(v) for k, v in zip(cols, sol[1:])})
            res[c] = (float(np.clip(coef["load_force_n"], lo, hi)), float(np.clip(coef["load_mass_kg"], 0.0, 0.05)))
        return res

    def after(rows: pd.DataFrame, s: dict[str, tuple[float, float]]) -> np.ndarray:
        per_n = rows["conveyor_id"].map({c: v[0] for c, v in s.items()}).to_numpy(float)
        per_kg = rows["conveyor_id"].map({c: v[1] for c, v in s.items()}).to_numpy(float)
        return (rows["residual_mps"].to_numpy() + per_n * rows["load_force_n"].to_numpy()
                + per_kg * rows["load_mass_kg"].to_numpy())

    u, e0 = np.zeros(len(runs)), np.zeros(len(runs))
    for fold in folds(runs):
        s = slopes(d[~d["run_id"].isin(fold)])
        for j, r in enumerate(runs):
            if r in fold:
                rr = d[d["run_id"] == r]
                # the offset of each drive is no droop: it is the same with and without the candidate
                base = rr["residual_mps"].to_numpy() - rr.groupby("conveyor_id")["residual_mps"].transform("mean").to_numpy()
                moved = after(rr, s)
                moved = moved - pd.Series(moved, index=rr.index).groupby(rr["conveyor_id"]).transform("mean").to_numpy()
                e0[j] = float(np.sum(base**2))
                u[j] = e0[j] - float(np.sum(moved**2))
    out.score(heldout_score(runs, u, e0, len(d), rng))
    per = slopes(d)
    boot = [slopes(pd.concat([d[d["run_id"] == runs[i]] for i in rng.integers(0, len(runs), len(runs))]))
            for _ in range(200)]
    out.values[pname] = float(np.mean([v[0] for v in per.values()]))
    out.ci95[pname] = tuple(float(np.percentile([np.mean([v[0] for v in b.values()]) for b in boot], q))
                            for q in (2.5, 97.5))
    for c in conveyors:
        for k, key in ((0, f"{pname}[{c}]"), (1, f"droop_per_kg[{c}]")):
            out.values[key] = per[c][k]
            out.ci95[key] = tuple(float(np.percentile([b[c][k] for b in boot], q)) for q in (2.5, 97.5))
        # the whole fitted loss against the mass carried: the force bringing fish up to speed grows with the mass
        # too, and the two terms share the droop between them (what a speed lost per kg is, in the data's loads)
        rc = d[d["conveyor_id"] == c]
        var_m = float(np.var(rc["load_mass_kg"]))
        share = float(np.cov(rc["load_force_n"], rc["load_mass_kg"], bias=True)[0, 1]) / var_m if var_m > 1e-12 else 0.0
        out.values[f"speed_lost_per_kg[{c}]"] = per[c][1] + per[c][0] * share
    return out


def terms(values: dict[str, float], ctx: Terms) -> dict[str, float]:
    """The share of each belt's speed lost per 10 kg of fish carried (its typical setpoint; both fitted terms, the
    one per kg and the one per newton bringing fish up to speed, against the mass in the data's loads), and their
    mean over the belts."""
    out = {}
    for key, per_kg in values.items():
        belt = key[key.find("[") + 1:-1]
        if key.startswith("speed_lost_per_kg[") and belt in ctx.setpoint_mps:
            out[f"speed_lost_per_10kg[{belt}]"] = float(10.0 * per_kg / ctx.setpoint_mps[belt])
    if out:
        out["speed_lost_per_10kg"] = float(np.mean(list(out.values())))
    return out


def plot(ax, rows: dict[str, pd.DataFrame]) -> None:
    """Its signature as the test reads it: each drive's sag below its setpoint against the mass on its belt."""
    drive = rows.get("drive")
    if drive is not None and len(drive):
        ax.plot(drive["load_kg"], 100 * drive["sag"], ",", alpha=0.5)
    ax.set(xlabel="mass on the belt [kg]", ylabel="speed below setpoint [%]")


CANDIDATE = Candidate(
    "drive_droop", "belt creep on its drum: belt speed drop per newton of load", ("belt_slip",), "(m/s)/N", 0.0, (),
    (0.0, 0.01), "drive", apply, ("belt_slip",), test=test,
    decides="drive logs of runs whose belts carry varying loads (batches dumped onto the infeed)",
    fit=fit, synthetic=hide, terms=terms, primary="speed_lost_per_10kg",
    explains=(("drive", "load_kg"),), plot=plot)
