"""What the simulation gets wrong, fish by fish: residuals and the conditions they happened in.

From a measured run and its re-simulation (same fish, drops, belt speeds):

- **track errors**: the simulated mid-point interpolated at each measured sample, minus the
  measured one (along the line ``ex_m``, across ``ey_m``, heading ``eyaw_rad``);
- **belt residuals** (one row per fish and belt it rode alone on): the median along-line error
  while the fish lay wholly on that belt, and its change since the previous belt (``lag_m``).
  The change across a transfer is what friction decides (a fish slips until it has caught up
  with the faster belt), so it is the quantity in which friction effects show; the row carries
  the fish's heading on the belt, hours post mortem, and whether another fish was within a fish
  length (``crowded``), the conditions in which the candidate causes differ;
- **pair residuals**: for two fish touching when the leading one crosses a transfer, how much
  further apart the simulation has them a little later than the measurement (adhesion keeps
  touching fish together);
- **photo-eye passages**: the share of a fish's passage (riding alone) past a beam during which the
  beam is blocked, per beam the simulated mean minus the measured one.  A fish that lies limp on
  the belt blocks a low beam throughout; one stiff in rigor does not settle into the belt and lets
  the beam through under an arched part, so the beam flickers.  Friction hardly changes it: the
  signature that tells rigor from mucus.
(The drive residuals are :func:`fishfmu.analysis.drive_response.drive_residuals`.)

And one measure of the data alone, no simulation: the **drop lag** of a fish dropped onto the
infeed with no other fish near, the time it has lost to the belt once it moves with it (how far it
stays behind a point moving with the belt from where it was dropped, over the belt's speed: its fall
and about half the time it slides).  Friction sets the sliding (a slippery fish slides longer), so
across runs it shows friction changing without any model.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from dataclasses import dataclass, field

from plant.fish.fish_data import length_regressions
from plant.contract.line import Line
from plant.contract.measured import Dataset, Run

EDGE_M = 0.05
"""A fish counts as lying on a belt when its ends are this far inside the belt's ends."""

# Every table here has explicit column dtypes, empty or not: pandas 3 keeps the dtype of an empty
# frame in a concat, so an untyped empty table (object columns) would turn a boolean column of the
# concatenated rows into object, where ``~`` is bitwise on Python ints (~False == -1), not a negation.
TRACK_ERROR_DTYPES = {"fish_id": object, "t_s": float, "x_m": float, "y_m": float, "yaw_rad": float,
                      "ex_m": float, "ey_m": float, "eyaw_rad": float}
BELT_RESIDUAL_DTYPES = {"run_id": object, "fish_id": object, "belt": "int64", "conveyor_id": object,
                        "t_start_s": float, "t_end_s": float, "offset_m": float, "lag_m": float, "heading": float,
                        "hours_post_mortem": float, "length_m": float, "crowded": bool, "n_samples": "int64"}
PAIR_RESIDUAL_DTYPES = {"run_id": object, "leader": object, "follower": object, "conveyor_id": object,
                        "t_s": float, "separation_m": float, "dsep_m": float, "parting_m": float}
PASSAGE_RESIDUAL_DTYPES = {"run_id": object, "sensor_id": object, "n": "int64", "blocked_measured": float,
                           "blocked_simulated": float, "dblocked": float, "se": float}
DRIVE_RESIDUAL_DTYPES = {"run_id": object, "conveyor_id": object, "t_s": float, "residual_mps": float,
                         "load_force_n": float, "load_mass_kg": float}


def typed_frame(rows: list[dict] | pd.DataFrame, dtypes: dict) -> pd.DataFrame:
    """``rows`` as a frame with exactly these columns and dtypes (also when there are no rows)."""
    df = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows, columns=list(dtypes))
    return df.astype({c: t for c, t in dtypes.items() if c in df.columns})


def concat_typed(frames: list[pd.DataFrame], dtypes: dict) -> pd.DataFrame:
    """Frames one after the other, with the columns of ``dtypes`` in those dtypes (an empty list: no rows)."""
    frames = [f for f in frames if len(f)]
    if not frames:
        return typed_frame([], dtypes)
    return typed_frame(pd.concat(frames, ignore_index=True), dtypes)


def alone(rows: pd.DataFrame) -> pd.DataFrame:
    """The belt-residual rows of fish alone on their belt (``crowded`` is False; never a bitwise ``~``)."""
    crowded = rows["crowded"]
    if crowded.dtype != bool:
        raise TypeError(f"belt residuals: column 'crowded' has dtype {crowded.dtype}, expected bool")
    return rows[~crowded]


def track_errors(measured: pd.DataFrame, simulated: pd.DataFrame, max_gap_s: float = 0.2) -> pd.DataFrame:
    """Simulated mid-point and heading interpolated at each measured sample, minus the measured ones.

    Samples where the simulation has no track within ``max_gap_s`` (before its drop, after it left)
    are left out.
    """
    rows = []
    for fid, m in measured.groupby("fish_id", sort=False):
        s = simulated[simulated["fish_id"] == fid]
        if len(s) < 2:
            continue
        ts, tm = s["t_s"].to_numpy(float), m["t_s"].to_numpy(float)
        idx = np.clip(np.searchsorted(ts, tm), 1, len(ts) - 1)
        near = np.minimum(np.abs(ts[idx] - tm), np.abs(ts[idx - 1] - tm)) <= max_gap_s
        ok = near & (tm >= ts[0]) & (tm <= ts[-1])
        if not np.any(ok):
            continue
        yaw_s = np.unwrap(s["yaw_rad"].to_numpy(float))
        sx = np.interp(tm[ok], ts, s["x_m"].to_numpy(float))
        sy = np.interp(tm[ok], ts, s["y_m"].to_numpy(float))
        syaw = np.interp(tm[ok], ts, yaw_s)
        mm = m[ok]
        eyaw = np.angle(np.exp(1j * (syaw - mm["yaw_rad"].to_numpy(float))))
        rows.append(pd.DataFrame({"fish_id": fid, "t_s": tm[ok], "x_m": mm["x_m"].to_numpy(float),
                                  "y_m": mm["y_m"].to_numpy(float), "yaw_rad": mm["yaw_rad"].to_numpy(float),
                                  "ex_m": sx - mm["x_m"].to_numpy(float), "ey_m": sy - mm["y_m"].to_numpy(float),
                                  "eyaw_rad": eyaw}))
    return concat_typed(rows, TRACK_ERROR_DTYPES)


def crowding(tracks: pd.DataFrame, fid: str, t0: float, t1: float, radius_m: float) -> bool:
    """Was another fish's mid-point within radius_m of this one's at some sample in [t0, t1]?"""
    window = tracks[(tracks["t_s"] >= t0 - 0.05) & (tracks["t_s"] <= t1 + 0.05)]
    me = window[window["fish_id"] == fid]
    others = window[window["fish_id"] != fid]
    if me.empty or others.empty:
        return False
    t_me, x_me, y_me = me["t_s"].to_numpy(), me["x_m"].to_numpy(), me["y_m"].to_numpy()
    t_o = others["t_s"].to_numpy()
    j = np.clip(np.searchsorted(t_me, t_o), 0, len(t_me) - 1)
    close_t = np.abs(t_me[j] - t_o) <= 0.05
    d = np.hypot(others["x_m"].to_numpy() - x_me[j], others["y_m"].to_numpy() - y_me[j])
    return bool(np.any(close_t & (d < radius_m)))


def belt_residuals(run: Run, errors: pd.DataFrame, line: Line) -> pd.DataFrame:
    """One row per fish and belt it lay wholly on: median along-line error there (robust to a tracker's outliers), change since the last belt."""
    fish = run.fish.set_index("fish_id")
    rows = []
    for fid, e in errors.groupby("fish_id", sort=False):
        length = float(fish.loc[fid, "length_m"])
        hours = fish.loc[fid, "hours_post_mortem"] if "hours_post_mortem" in fish.columns else np.nan
        hours = float(hours) if pd.notna(hours) else float(run.hours_post_mortem or np.nan)
        prev_offset, prev_t_end = 0.0, float(fish.loc[fid, "drop_t_s"])
        for k, c in enumerate(line.conveyors):
            on = e[(e["x_m"] - 0.5 * length > c.x_start_m + EDGE_M) & (e["x_m"] + 0.5 * length < c.x_end_m - EDGE_M)]
            if len(on) < 5:
                continue
            offset = float(on["ex_m"].median())
            t0, t1 = float(on["t_s"].iloc[0]), float(on["t_s"].iloc[-1])
            crowded = crowding(run.tracks, fid, prev_t_end, t1, length)
            rows.append({"run_id": run.id, "fish_id": fid, "belt": k, "conveyor_id": c.id, "t_start_s": t0,
                         "t_end_s": t1, "offset_m": offset, "lag_m": offset - prev_offset,
                         "heading": float(np.median(np.cos(on["yaw_rad"].to_numpy()))),
                         "hours_post_mortem": hours, "length_m": length, "crowded": crowded,
                         "n_samples": len(on)})
            prev_offset, prev_t_end = offset, t1
    return typed_frame(rows, BELT_RESIDUAL_DTYPES)


@dataclass(frozen=True)
class SideBySide:
    """Two fish side by side when the leading one's mid-point first crosses a point of the line (a transfer)."""

    leader: str
    follower: str
    t_s: float
    """The first tracked time the leader is past the point."""
    dx_m: float
    """The leader's mid-point ahead of the follower's (> 0), less than they overlap by a quarter of the shorter."""
    dy_m: float
    """Their mid-points apart across the line."""
    half_heights_m: float
    """Half the sum of their heights (a fish lies on its side: its height is its width on the belt)."""


def fish_heights(fish: pd.DataFrame) -> pd.Series:
    """Each fish's height (by fish id), the length regression's where fish.csv leaves it out."""
    fish = fish.set_index("fish_id")
    height = fish["height_m"] if "height_m" in fish.columns else pd.Series(np.nan, index=fish.index)
    return height.astype(float).fillna(pd.Series(length_regressions().height_m(fish["length_m"].to_numpy()),
                                                 index=fish.index))


def side_by_side_at(tracks: pd.DataFrame, fish: pd.DataFrame, x_m: float,
                    sort: bool = False) -> list[SideBySide]:
    """Every pair of fish overlapping along the line by at least a quarter of the shorter (tracked within 30 ms)
    when the leading one's mid-point first crosses ``x_m``; leaders in the tracks' order (``sort``: by fish id)."""
    length = fish.set_index("fish_id")["length_m"]
    height = fish_heights(fish)
    out = []
    for fid, m in tracks.groupby("fish_id", sort=sort):
        x, t = m["x_m"].to_numpy(), m["t_s"].to_numpy()
        cross = np.flatnonzero((x[:-1] < x_m) & (x[1:] >= x_m))
        if not len(cross):
            continue
        tc = float(t[cross[0] + 1])
        at = tracks[np.abs(tracks["t_s"] - tc) <= 0.03]
        me = at[at["fish_id"] == fid]
        if me.empty:
            continue
        for o in at[at["fish_id"] != fid].drop_duplicates("fish_id").itertuples(index=False):
            dx = float(me["x_m"].iloc[0] - o.x_m)
            la, lb = float(length[fid]), float(length[o.fish_id])
            if not 0.0 < dx < 0.5 * (la + lb) - 0.25 * min(la, lb):
                continue
            out.append(SideBySide(fid, o.fish_id, tc, dx, abs(float(me["y_m"].iloc[0] - o.y_m)),
                                  0.5 * float(height[fid] + height[o.fish_id])))
    return out


MIN_PARTING_MPS = 0.05
"""Belts closer in speed than this at a transfer do not part the pairs crossing it enough to read."""


def transfer_speed_steps(run: Run, line: Line) -> list[tuple]:
    """(the downstream conveyor, how much faster it runs than the one before) at each transfer, from the run's
    logged belt speeds (each belt's median over the run)."""
    belts = run.belts
    speed = [float(belts.loc[belts["conveyor_id"] == c.id, "speed_mps"].median()) for c in line.conveyors]
    return [(c, speed[k] - speed[k - 1]) for k, c in enumerate(line.conveyors[1:], start=1)]


def pair_residuals(run: Run, simulated: pd.DataFrame, line: Line, after_s: float = 1.5) -> pd.DataFrame:
    """Pairs of fish touching (side by side within their heights and 2 cm, overlapping along the line) when the
    leading one crosses a transfer: separation along the line ``after_s`` later, simulated minus measured, and
    ``parting_m``: the measured belts' speed difference there (median over the run) x ``after_s``, NaN below 0.05 m/s."""
    rows = []
    for c, dv in transfer_speed_steps(run, line):
        parting_m = dv * after_s if dv >= MIN_PARTING_MPS else float("nan")
        for p in side_by_side_at(run.tracks, run.fish, c.x_start_m):
            if not p.dy_m < p.half_heights_m + 0.02:
                continue
            sep_m = _separation(run.tracks, p.leader, p.follower, p.t_s + after_s)
            sep_s = _separation(simulated, p.leader, p.follower, p.t_s + after_s)
            if sep_m is not None and sep_s is not None:
                rows.append({"run_id": run.id, "leader": p.leader, "follower": p.follower, "conveyor_id": c.id,
                             "t_s": p.t_s, "separation_m": sep_m, "dsep_m": sep_s - sep_m, "parting_m": parting_m})
    return typed_frame(rows, PAIR_RESIDUAL_DTYPES)


REACH_M = 0.4
"""A fish is at a beam when its mid-point is this close (half the longest salmon of the contract's range)."""


DROP_LAG_WINDOW_S = (1.5, 3.0)
"""After its drop, when a fish's lag on the infeed is read [s]: it has landed and moves with the belt."""


def drop_lags(run: Run, line: Line) -> pd.DataFrame:
    """Per fish dropped onto the first belt with no other fish within a fish length until it is read: its drop
    lag [s] (see the module docstring), the mean over the samples in :data:`DROP_LAG_WINDOW_S` after the drop
    while it lies wholly on the first belt, at the belt's logged median speed there."""
    dtypes = {"fish_id": object, "drop_lag_s": float, "belt_speed_mps": float, "n_samples": "int64"}
    belt = line.conveyors[0]
    logged = run.belts[run.belts["conveyor_id"] == belt.id]
    rows = []
    for f in run.fish.itertuples(index=False):
        t0, t1 = f.drop_t_s + DROP_LAG_WINDOW_S[0], f.drop_t_s + DROP_LAG_WINDOW_S[1]
        tr = run.tracks[(run.tracks["fish_id"] == f.fish_id) & (run.tracks["t_s"] >= t0) & (run.tracks["t_s"] <= t1)]
        tr = tr[tr["x_m"] + 0.5 * f.length_m < belt.x_end_m - EDGE_M]
        v = logged[(logged["t_s"] >= f.drop_t_s) & (logged["t_s"] <= t1)]["speed_mps"]
        if len(tr) < 5 or v.empty or float(v.median()) < 0.05 or crowding(run.tracks, f.fish_id, f.drop_t_s, t1,
                                                                         float(f.length_m)):
            continue
        speed = float(v.median())
        lag = f.drop_x_m + speed * (tr["t_s"].to_numpy(float) - f.drop_t_s) - tr["x_m"].to_numpy(float)
        rows.append({"fish_id": f.fish_id, "drop_lag_s": float(np.mean(lag)) / speed, "belt_speed_mps": speed,
                     "n_samples": len(tr)})
    return typed_frame(rows, dtypes)


def photoeye_passages(tracks: pd.DataFrame, photoeyes: pd.DataFrame, fish: pd.DataFrame, line: Line,
                   min_cos: float = 0.8) -> pd.DataFrame:
    """Per passage of a fish alone past a beam, riding along the line (|cos yaw| >= ``min_cos``): from its first
    blocked moment to its last, ``blocked`` the share of that time the beam was blocked (1: no flicker),
    ``intervals`` how many blocked intervals, ``span`` the passage's time x the fish's speed over it / (its
    length x |cos yaw|) (1 for a straight fish the beam sees whole).  A blocked interval is a fish's when it
    is the only fish within ``REACH_M`` of the beam at the interval's middle (a tracked position within
    0.03 s); a fish's intervals at one beam are one passage, from ``t_s`` (its first edge on) to ``t_end_s`` (its
    last edge off)."""
    beam_x = {p.id: p.x_m for p in line.photoeyes}
    length = fish.set_index("fish_id")["length_m"]
    dtypes = {"fish_id": object, "sensor_id": object, "t_s": float, "t_end_s": float, "span": float,
              "blocked": float, "intervals": "int64"}
    if tracks.empty or photoeyes.empty:
        return typed_frame([], dtypes)
    order = np.argsort(tracks["t_s"].to_numpy(float), kind="stable")
    tracks = tracks.iloc[order]
    t_sorted = tracks["t_s"].to_numpy(float)
    hits = []
    for sensor, t_on, t_off in photoeyes[["sensor_id", "t_on_s", "t_off_s"]].itertuples(index=False):
        xb = beam_x.get(sensor)
        if xb is None or t_off <= t_on:
            continue
        tm = 0.5 * (t_on + t_off)
        lo, hi = np.searchsorted(t_sorted, [tm - 0.03, tm + 0.03])
        at = tracks.iloc[lo:hi]
        at = at[np.abs(at["x_m"].to_numpy(float) - xb) < REACH_M]
        if at["fish_id"].nunique() == 1 and at["fish_id"].iloc[0] in length.index:
            yaw = at["yaw_rad"].iloc[int(np.argmin(np.abs(at["t_s"].to_numpy(float) - tm)))]
            hits.append((at["fish_id"].iloc[0], sensor, float(t_on), float(t_off), abs(float(np.cos(yaw)))))
    rows = []
    for (fid, sensor), g in pd.DataFrame(hits, columns=["fish_id", "sensor_id", "t_on", "t_off", "cos"]).groupby(
            ["fish_id", "sensor_id"], sort=False):
        t_on, t_off, cos = g["t_on"].min(), g["t_off"].max(), float(g["cos"].median())
        lo, hi = np.searchsorted(t_sorted, [t_on, t_off])
        me = tracks.iloc[lo:hi]
        me = me[me["fish_id"] == fid]
        if cos < min_cos or len(me) < 3:
            continue
        speed = (me["x_m"].iloc[-1] - me["x_m"].iloc[0]) / (me["t_s"].iloc[-1] - me["t_s"].iloc[0])
        rows.append({"fish_id": fid, "sensor_id": sensor, "t_s": float(t_on), "t_end_s": float(t_off),
                     "span": float((t_off - t_on) * speed / (float(length[fid]) * cos)),
                     "blocked": float((g["t_off"] - g["t_on"]).sum() / (t_off - t_on)), "intervals": len(g)})
    return typed_frame(rows, dtypes)


MIN_PASSAGE_SE = 0.005
"""Floor of a beam's standard error: passages that never flicker, measured or simulated, have no spread, but a
share measured from 25 Hz tracks and a few fish is not known to better than half a percent."""


def passage_residuals(run: Run, sim_tracks: pd.DataFrame, sim_photoeyes: pd.DataFrame, line: Line) -> pd.DataFrame:
    """Per beam: the mean blocked share (:func:`photoeye_passages`) of the simulated passages minus that of
    the measured ones, over the passages of the same fish at that beam found in both (at least three), and the
    standard error of that difference from the spread over the fish (at least ``MIN_PASSAGE_SE``)."""
    m = photoeye_passages(run.tracks, run.photoeyes, run.fish, line)
    s = photoeye_passages(sim_tracks, sim_photoeyes, run.fish, line)
    both = m.merge(s, on=["fish_id", "sensor_id"], suffixes=("_m", "_s"))
    rows = [{"run_id": run.id, "sensor_id": sensor, "n": len(g), "blocked_measured": float(g["blocked_m"].mean()),
             "blocked_simulated": float(g["blocked_s"].mean()),
             "dblocked": float(g["blocked_s"].mean() - g["blocked_m"].mean()),
             "se": max(float(np.sqrt((g["blocked_s"].var() + g["blocked_m"].var()) / len(g))), MIN_PASSAGE_SE)}
            for sensor, g in both.groupby("sensor_id", sort=True) if len(g) >= 3]
    return typed_frame(rows, PASSAGE_RESIDUAL_DTYPES)


def _separation(tracks: pd.DataFrame, a: str, b: str, t: float) -> float | None:
    xs = []
    for fid in (a, b):
        m = tracks[tracks["fish_id"] == fid]
        if m.empty or t < m["t_s"].iloc[0] or t > m["t_s"].iloc[-1]:
            return None
        xs.append(float(np.interp(t, m["t_s"], m["x_m"])))
    return xs[0] - xs[1]


HEADING_SPLIT = 0.3
"""|cos(yaw)| above which a fish rides clearly head first or tail first."""


@dataclass
class RunResiduals:
    """One run's residuals against a re-simulation (:mod:`fishfmu.analysis.residuals`)."""

    run_id: str
    rows: pd.DataFrame
    pairs: pd.DataFrame
    track_rms_m: float
    error: str | None = None
    passages: pd.DataFrame = field(default_factory=lambda: typed_frame([], PASSAGE_RESIDUAL_DTYPES))
    """Per beam, simulated minus measured blocked share of fish passing alone (:func:`passage_residuals`)."""

    def squares(self, group: str | None = None) -> tuple[float, int]:
        """(sum of squares, count) of this run's residuals: lags of fish alone, extra pair separation.

        ``group``: ``head_first`` / ``tail_first`` rows only (no pairs), for direction friction;
        ``alone``: every fish alone, no pairs; ``transfers``: fish alone after a transfer (not on the first
        belt, where the lag is that of the drop), no pairs; ``drops``: fish alone on the first belt (the drop's
        lag); ``pairs``: the pairs only; ``pair_levels``: the run's pairs as one level, for adhesion (see
        :meth:`pair_level`)."""
        if group == "pair_levels":
            return self.pair_level()
        if group == "pairs":
            d = self.pairs["dsep_m"].to_numpy(float) if len(self.pairs) else np.zeros(0)
            return float(np.sum(d**2)), len(d)
        free = alone(self.rows)
        if group == "head_first":
            free = free[free["heading"] > HEADING_SPLIT]
        elif group == "tail_first":
            free = free[free["heading"] < -HEADING_SPLIT]
        elif group == "transfers":
            free = free[free["belt"] > 0]
        elif group == "drops":
            free = free[free["belt"] == 0]
        ss = float(np.sum(free["lag_m"].to_numpy(float) ** 2))
        n = len(free)
        if group is None and len(self.pairs):
            d = self.pairs["dsep_m"].to_numpy(float)
            ss, n = ss + float(np.sum(d**2)), n + len(d)
        return ss, n

    def pair_share(self) -> tuple[float, int]:
        """(mean, count) of the pairs' extra separation as a share of their ``parting_m`` (0: parted as measured;
        +1: parted where the measured pair stayed together); (nan, 0) without a pair that has one."""
        parting = self.pairs["parting_m"].to_numpy(float) if len(self.pairs) else np.zeros(0)
        ok = np.isfinite(parting)
        if not np.any(ok):
            return float("nan"), 0
        return float(np.mean(self.pairs["dsep_m"].to_numpy(float)[ok] / parting[ok])), int(ok.sum())

    def pair_level(self) -> tuple[float, int]:
        """(n x the squared :meth:`pair_share`, n): the run's pairs as one level. A force between fish changes how far
        a run's pairs part on the whole; which pair of a pile parts is chaos that no parameter predicts."""
        share, n = self.pair_share()
        return (n * share**2, n) if n else (0.0, 0)


def residuals_of(dataset: Dataset, resims: list) -> list[RunResiduals]:
    """Residuals of each run against its re-simulation (a :class:`~fishfmu.analysis.resim.Resim`; a failed
    re-simulation has none, and says why)."""
    out = []
    for run, r in zip(dataset.runs, resims):
        if r.residuals is not None:  # computed by the worker that re-simulated the run
            out.append(r.residuals)
            continue
        if r.error:
            empty = track_errors(run.tracks.iloc[0:0], run.tracks.iloc[0:0])
            out.append(RunResiduals(run.id, belt_residuals(run, empty, dataset.line),
                                    typed_frame([], PAIR_RESIDUAL_DTYPES), np.nan, r.error))
            continue
        errors = track_errors(run.tracks, r.sim.tracks)
        rms = float(np.sqrt(np.mean(errors["ex_m"] ** 2))) if len(errors) else np.nan
        out.append(RunResiduals(run.id, belt_residuals(run, errors, dataset.line),
                                pair_residuals(run, r.sim.tracks, dataset.line), rms,
                                passages=passage_residuals(run, r.sim.tracks, r.sim.photoeyes, dataset.line)))
    return out
