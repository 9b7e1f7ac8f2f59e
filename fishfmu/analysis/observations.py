"""The quantities each candidate cause changes, read from measured data alone (no model): the rows the covariate
tests of :mod:`fishfmu.analysis.signatures` read.

- :func:`drop_rows`: each fish dropped alone onto the first belt, the time it lost to the belt beyond its fall;
- :func:`passage_rows`: each passage of a fish alone past a photo-eye, the share of it the beam was blocked;
- :func:`edge_rows`: each passage of a fish alone past a photo-eye, how far past the beam the fish's head was when
  the eye reported it there;
- :func:`drive_rows`: each drive's speed below its setpoint against the mass on its belt (:func:`belt_loads`);
- :func:`pair_rows`: pairs of fish side by side at a transfer, how much of the belts' speed difference their
  separation gained;
- :func:`guide_rows`: each fish on each short stretch of belt it rode wholly on, how far it fell behind its belt's
  logged speed (slip) and whether it touched a side guide there.

The same readers serve a re-simulation written in the measured-data format, so that measured and modelled pairs
are compared on equal terms.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from plant.contract.line import Line
from plant.contract.measured import Dataset, Run

from fishfmu.analysis.residuals import (EDGE_M, MIN_PARTING_MPS, crowding, fish_heights, photoeye_passages,
                                        side_by_side_at, transfer_speed_steps)

G_MPS2 = 9.81
DROP_READ_S = (0.8, 3.0)
"""After its drop, when a fish's slip is read [s]: it has landed (a fall from 0.2 m takes 0.2 s) and slid up to the
belt's speed (0.3 s at the lowest plausible friction, 0.2, on the fastest infeed, 0.5 m/s), while it lies wholly on
the belt, for at most 3 s."""


def _fish_hours(run: Run) -> pd.Series:
    """Each fish's hours post mortem: its own where fish.csv gives it, else the run's."""
    fish = run.fish.set_index("fish_id")
    own = fish["hours_post_mortem"] if "hours_post_mortem" in fish.columns else pd.Series(np.nan, index=fish.index)
    return own.astype(float).fillna(float(run.hours_post_mortem) if run.hours_post_mortem is not None else np.nan)


def drop_rows(dataset: Dataset) -> pd.DataFrame:
    """Per fish dropped alone onto the first belt: its slip [s], the time it lost to the belt beyond its free fall
    (:func:`drop_slip`), with its run, hours post mortem, heading (cos of its yaw at the drop: +1 head downstream)
    and the belt's speed."""
    rows = []
    belt = dataset.line.conveyors[0]
    for run in dataset.runs:
        hours = _fish_hours(run)
        for f in run.fish.itertuples(index=False):
            read = drop_slip(f, run.tracks, run.belts, belt)
            if read is None or crowding(run.tracks, f.fish_id, f.drop_t_s, f.drop_t_s + DROP_READ_S[1],
                                        float(f.length_m)):
                continue
            rows.append({"run_id": run.id, "fish_id": f.fish_id, "hours_post_mortem": float(hours[f.fish_id]),
                         "heading": float(np.cos(f.drop_yaw_rad)), "belt_speed_mps": read[0], "slip_s": read[1]})
    return pd.DataFrame(rows, columns=["run_id", "fish_id", "hours_post_mortem", "heading", "belt_speed_mps",
                                       "slip_s"])


def drop_slip(f, tracks: pd.DataFrame, belts: pd.DataFrame, belt) -> tuple[float, float] | None:
    """(the belt's speed, the slip [s]) of fish ``f`` (a row of fish.csv) dropped onto ``belt``, from its tracks and
    the belt's logged speed: ``drop lag`` - sqrt(2 z / g), the drop lag the time its mid-point stayed behind where
    riding the belt from its drop would have put it, read while it lies wholly on the belt (:data:`DROP_READ_S`);
    None where that cannot be read (too few samples, the belt stopped).  Sliding alone it would be ``v / (2 mu g)``;
    landing and settling add a part that hardly depends on the speed, so the speed is a nuisance term of the tests,
    not a divisor.  The same reader serves a drop re-simulated alone (:func:`fishfmu.analysis.resim.resimulate_drops`)."""
    t0, t1 = f.drop_t_s + DROP_READ_S[0], f.drop_t_s + DROP_READ_S[1]
    tr = tracks[(tracks["fish_id"] == f.fish_id) & (tracks["t_s"] >= t0) & (tracks["t_s"] <= t1)]
    tr = tr[tr["x_m"] + 0.5 * f.length_m < belt.x_end_m - EDGE_M]
    logged = belts[belts["conveyor_id"] == belt.id]
    v = logged[(logged["t_s"] >= f.drop_t_s) & (logged["t_s"] <= t1)]["speed_mps"]
    if len(tr) < 5 or v.empty or float(v.median()) < 0.05:
        return None
    speed = float(v.median())
    lag_s = float(np.mean(f.drop_x_m + speed * (tr["t_s"].to_numpy(float) - f.drop_t_s)
                          - tr["x_m"].to_numpy(float))) / speed
    return speed, lag_s - float(np.sqrt(2.0 * max(float(f.drop_z_m), 0.0) / G_MPS2))


def passage_rows(dataset: Dataset) -> pd.DataFrame:
    """Per passage of a fish alone past a photo-eye: the share of it the beam was blocked, with run and hours."""
    frames = []
    for run in dataset.runs:
        p = photoeye_passages(run.tracks, run.photoeyes, run.fish, dataset.line)
        if len(p):
            hours = _fish_hours(run)
            frames.append(pd.DataFrame({"run_id": run.id, "fish_id": p["fish_id"].to_numpy(),
                                        "sensor_id": p["sensor_id"].to_numpy(),
                                        "hours_post_mortem": hours.reindex(p["fish_id"]).to_numpy(float),
                                        "blocked": p["blocked"].to_numpy(float)}))
    cols = ["run_id", "fish_id", "sensor_id", "hours_post_mortem", "blocked"]
    return pd.concat(frames, ignore_index=True)[cols] if frames else pd.DataFrame(columns=cols)


EDGE_FIT_S = 0.12
"""A fish's position and speed at a photo-eye's edge are read from a straight line fitted to its track within +-this
of the edge (seven samples at 25 Hz): a few mm of tracking noise per sample would otherwise be the offset."""


def _at_edge(t: np.ndarray, x: np.ndarray, t_edge: float) -> tuple[float, float] | None:
    """(position, speed) of a track at ``t_edge`` from a line through its samples within :data:`EDGE_FIT_S`."""
    near = np.abs(t - t_edge) <= EDGE_FIT_S
    if near.sum() < 3 or t[near].min() > t_edge or t[near].max() < t_edge:
        return None
    v, x0 = np.polyfit(t[near] - t_edge, x[near], 1)
    return float(x0), float(v)


def edge_rows(dataset: Dataset) -> pd.DataFrame:
    """Per passage of a fish alone past a photo-eye (:func:`photoeye_passages`: riding along the line, no other fish
    at the beam; and no other fish's mid-point within its length and 0.1 m of its own from :data:`EDGE_FIT_S` before
    the passage to as long after it), lying wholly on the belt under the beam when its head reaches it:
    ``offset_m``, how far its leading end was past the beam (its tracked mid-point plus half its length along the
    line) when the eye reported the edge on, and ``speed_mps``, its tracked speed then.  On time, the offset is where
    the blocked part of its outline begins behind its tip (shape, heading, length: a distance, the same at any
    speed); for an eye reporting its edges ``L`` late, plus the way the fish travelled in that time, ``L`` x
    ``speed_mps``.  The edge off is not read: the tail leaves a beam near a belt's end while the fish crosses the
    transfer, where how it bridges the step (its stiffness, its speed) moves the tail by a distance that follows the
    speed without any delay (rigor in the independent simulator's data: 76 ms per m/s from both edges, none from the
    edge on).  An eye's ``latency_s`` in the line is taken off its edge first: what is left is a latency the line
    does not know of.  With the logged speed of the belt under the beam, run, fish, its hours, weight, length,
    heading (cos of its yaw: +1 head downstream) and the time in the run."""
    cols = ["run_id", "fish_id", "sensor_id", "offset_m", "speed_mps", "belt_speed_mps", "hours_post_mortem",
            "weight_kg", "length_m", "heading", "t_in_run_s"]
    beam_x = {p.id: p.x_m for p in dataset.line.photoeyes}
    latency = {p.id: p.latency_s for p in dataset.line.photoeyes}
    rows = []
    for run in dataset.runs:
        p = photoeye_passages(run.tracks, run.photoeyes, run.fish, dataset.line)
        if not len(p):
            continue
        hours, fish = _fish_hours(run), run.fish.set_index("fish_id")
        tracks = {fid: m.sort_values("t_s") for fid, m in run.tracks.groupby("fish_id", sort=False)}
        for q in p.itertuples(index=False):
            tr = tracks[q.fish_id]
            t, x = tr["t_s"].to_numpy(float), tr["x_m"].to_numpy(float)
            on = _at_edge(t, x, q.t_s - latency[q.sensor_id])  # the edge as it happened, by what the line says
            xb, length = beam_x[q.sensor_id], float(fish.loc[q.fish_id, "length_m"])
            belt = dataset.line.conveyor_at(xb)
            during = tr[(tr["t_s"] >= q.t_s) & (tr["t_s"] <= q.t_end_s)]["yaw_rad"].to_numpy(float)
            if on is None or not len(during):
                continue
            half = 0.5 * length * abs(float(np.median(np.cos(during))))
            if on[0] - half < belt.x_start_m + EDGE_M:
                continue  # still crossing onto this belt: a step down moves its head without a delay
            if crowding(run.tracks, q.fish_id, q.t_s - EDGE_FIT_S, q.t_end_s + EDGE_FIT_S, length + 0.1):
                continue  # a neighbour within a fish length may have cut the beam
            logged = run.belts[(run.belts["conveyor_id"] == belt.id) & (run.belts["t_s"] >= q.t_s)
                               & (run.belts["t_s"] <= q.t_end_s)]["speed_mps"]
            rows.append({"run_id": run.id, "fish_id": q.fish_id, "sensor_id": q.sensor_id,
                         "offset_m": on[0] + half - xb, "speed_mps": on[1],
                         "belt_speed_mps": float(logged.median()) if len(logged) else float("nan"),
                         "hours_post_mortem": float(hours[q.fish_id]),
                         "weight_kg": float(fish.loc[q.fish_id, "weight_kg"]), "length_m": length,
                         "heading": float(np.median(np.cos(during))), "t_in_run_s": float(q.t_s)})
    return pd.DataFrame(rows, columns=cols)


LOAD_GRID_S = 0.04
"""Tracks are put on this grid (their own rate is about 25 Hz); a fish lost by the tracker for a moment (under
another) is interpolated between its samples, so the load does not drop when the tracker loses it."""
DRIVE_WINDOW_S = 0.5
"""Belt speed and load are averaged over windows this long: droop follows a load that changes over tenths of a
second, while an encoder's sample-to-sample noise is no droop."""
SMOOTH_S = 0.12
"""A fish's track is smoothed over +-this before its acceleration is read: a few mm of tracking noise at 25 Hz
would otherwise be accelerations of metres per second squared."""
DRIVE_SETTLE_S = 3.0
"""A window counts only this long after the setpoint last changed: a drive's response to a step (a lag or a
ramp) is not droop."""


def belt_loads(run: Run, line: Line, t_s: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per conveyor at times ``t_s`` (a regular grid): the mass lying on it [kg] and the force with which it brings
    fish up to its speed [N], from the tracked mid-points, yaws and the fish's weights: each fish's weight shared
    between belts by how much of its length lies over each, and its mass times its acceleration (along the line,
    where positive, over :data:`SMOOTH_S`) shared the same way."""
    loads = {c.id: (np.zeros(len(t_s)), np.zeros(len(t_s))) for c in line.conveyors}
    fish = run.fish.set_index("fish_id")
    dt = float(t_s[1] - t_s[0]) if len(t_s) > 1 else LOAD_GRID_S
    k = max(1, int(round(SMOOTH_S / dt)))
    for fid, tr in run.tracks.groupby("fish_id", sort=False):
        t = tr["t_s"].to_numpy(float)
        inside = (t_s >= t[0]) & (t_s <= t[-1])
        if not inside.any():
            continue
        x = np.interp(t_s[inside], t, tr["x_m"].to_numpy(float))
        c = np.interp(t_s[inside], t, np.abs(np.cos(tr["yaw_rad"].to_numpy(float))))
        xs = np.convolve(np.pad(x, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="same")[k:-k]
        accel = np.clip(np.gradient(np.gradient(xs, dt), dt), 0.0, None) if len(xs) > 2 else np.zeros(len(xs))
        half = 0.5 * float(fish.loc[fid, "length_m"]) * np.maximum(c, 0.2)
        weight = float(fish.loc[fid, "weight_kg"])
        for conv in line.conveyors:
            share = np.clip(np.minimum(x + half, conv.x_end_m) - np.maximum(x - half, conv.x_start_m), 0.0, None) / (
                2.0 * half)
            loads[conv.id][0][inside] += weight * share
            loads[conv.id][1][inside] += weight * accel * share
    return loads


def drive_rows(dataset: Dataset) -> pd.DataFrame:
    """Per run, conveyor and window of :data:`DRIVE_WINDOW_S` with a settled setpoint: the logged speed's
    shortfall from the setpoint as a share of it (``sag``), the mass on the belt [kg] and the force with which it
    brings fish up to its speed [N] (:func:`belt_loads`)."""
    rows = []
    for run in dataset.runs:
        b = run.belts
        if b.empty:
            continue
        t_end = float(b["t_s"].max())
        grid = np.arange(0.0, t_end, LOAD_GRID_S)
        loads = belt_loads(run, dataset.line, grid)
        for conv in dataset.line.conveyors:
            log = b[b["conveyor_id"] == conv.id]
            if len(log) < 10:
                continue
            t = log["t_s"].to_numpy(float)
            sp = log["setpoint_mps"].to_numpy(float)
            changed = np.concatenate([[t[0]], t[1:][np.abs(np.diff(sp)) > 1e-9]])
            last_change = changed[np.searchsorted(changed, t, side="right") - 1]
            ok = (t - last_change >= DRIVE_SETTLE_S) & (np.abs(sp) > 0.05)
            if ok.sum() < 10:
                continue
            w = np.floor(t[ok] / DRIVE_WINDOW_S).astype(int)
            frame = pd.DataFrame({"w": w, "t": t[ok], "sag": 1.0 - log["speed_mps"].to_numpy(float)[ok] / sp[ok]})
            g = frame.groupby("w")
            mean = g.mean()
            enough = g.size() >= 0.5 * DRIVE_WINDOW_S / max(float(np.median(np.diff(t))), 1e-6)
            mean = mean[enough]
            mass, force = loads[conv.id]
            per = int(round(DRIVE_WINDOW_S / LOAD_GRID_S))  # grid samples per window: the window's mean load
            slices = [slice(w * per, (w + 1) * per) for w in mean.index.to_numpy()]
            rows.append(pd.DataFrame({"run_id": run.id, "conveyor_id": conv.id, "t_s": mean["t"].to_numpy(),
                                      "sag": mean["sag"].to_numpy(),
                                      "load_kg": [float(np.mean(mass[sl])) if len(mass[sl]) else 0.0 for sl in slices],
                                      "load_force_n": [float(np.mean(force[sl])) if len(force[sl]) else 0.0
                                                       for sl in slices]}))
    cols = ["run_id", "conveyor_id", "t_s", "sag", "load_kg", "load_force_n"]
    return pd.concat(rows, ignore_index=True)[cols] if rows else pd.DataFrame(columns=cols)


PAIR_AFTER_S = 1.5
"""How long after the leading fish of a pair crosses a transfer their separation is read."""
PAIR_SIDE_GAP_M = (0.02, 0.15)
"""Side by side but not touching: the gap between the fish's flanks (from their mid-points' distance across the
line less half their heights) within this range; touching: below zero. In between is left out: a few mm of
tracking noise cannot tell touching from not."""


def pair_rows(dataset: Dataset) -> pd.DataFrame:
    """Per pair of fish side by side (overlapping along the line by at least a quarter of the shorter) when the
    leading one's mid-point crosses a transfer: how much of the belts' speed difference their separation gained
    over :data:`PAIR_AFTER_S` (``growth``: 1 when each rode its own belt throughout), and whether they touched.
    Without a force between fish in contact, touching pairs part as pairs with a gap do; adhesion holds them."""
    rows = []
    for run in dataset.runs:
        by_fish = {fid: (m["t_s"].to_numpy(float), m["x_m"].to_numpy(float))
                   for fid, m in run.tracks.groupby("fish_id")}
        for c, dv in transfer_speed_steps(run, dataset.line):
            if not dv >= MIN_PARTING_MPS:  # NaN too: a belt without a log
                continue
            for p in side_by_side_at(run.tracks, run.fish, c.x_start_m, sort=True):
                gap = p.dy_m - p.half_heights_m
                if gap >= PAIR_SIDE_GAP_M[1] or 0.0 <= gap < PAIR_SIDE_GAP_M[0]:
                    continue
                (t, x), (to, xo) = by_fish[p.leader], by_fish[p.follower]
                t1 = p.t_s + PAIR_AFTER_S
                if t1 > t[-1] or t1 > to[-1]:
                    continue
                sep = float(np.interp(t1, t, x) - np.interp(t1, to, xo))
                rows.append({"run_id": run.id, "conveyor_id": c.id, "leader": p.leader, "follower": p.follower,
                             "touching": float(gap < 0.0), "growth": (sep - p.dx_m) / (dv * PAIR_AFTER_S)})
    cols = ["run_id", "conveyor_id", "leader", "follower", "touching", "growth"]
    return pd.DataFrame(rows, columns=cols)


STRETCH_M = 0.25
"""Each belt is read in stretches this long (by the fish's tracked mid-point): short enough to place a guide's
grip along the line, long enough (0.25-1 s of track at 0.25-1 m/s) to read a speed through a few mm of tracking
noise."""
GUIDE_TOUCH_M = (0.005, 0.015)
"""A fish touches a guide on a stretch when the median gap between its flank and the nearer guide (its tracked
mid-point and yaw, its length and height as an ellipse seen from above) is below the first; it is clear of both when
the gap is above the second.  In between is left out: a few mm of tracking noise and a fish's outline that is no
exact ellipse cannot tell touching from not."""


def guide_gap_m(line: Line, x_m: np.ndarray, y_m: np.ndarray, yaw_rad: np.ndarray, length_m: float,
                height_m: float) -> np.ndarray:
    """The gap between a fish's flank and the nearer side guide [m] (< 0: overlapping it, as a bent fish or a
    tracker's error may), the fish seen from above as an ellipse of its length and height (it lies on its side)."""
    half = np.hypot(0.5 * length_m * np.sin(yaw_rad), 0.5 * height_m * np.cos(yaw_rad))
    left, right = line.guide_y_at(x_m)
    return np.minimum(left - (y_m + half), (y_m - half) - right)


def guide_rows(dataset: Dataset) -> pd.DataFrame:
    """Per fish and stretch of :data:`STRETCH_M` of a belt it lay wholly on (at least 5 samples over 0.2 s): its
    slip [m/s], the belt's logged mean speed there less the fish's speed along the line (a line fitted to its
    tracked x over time), and ``touching`` 1 (its flank at a guide) or 0 (clear of both; see :data:`GUIDE_TOUCH_M`,
    the band between left out), with the stretch's mid x, the fish's properties, its heading (the median of the
    cos of its yaw: +1 head downstream) and how long into the run.  A guide holds back only the fish pressed against it, by its friction there:
    fish clear of the guides show what the stretch itself does."""
    rows = []
    for run in dataset.runs:
        fish = run.fish.set_index("fish_id")
        hours, height = _fish_hours(run), fish_heights(run.fish)
        for fid, tr in run.tracks.groupby("fish_id", sort=True):
            length = float(fish.loc[fid, "length_m"])
            t, x = tr["t_s"].to_numpy(float), tr["x_m"].to_numpy(float)
            yaw = tr["yaw_rad"].to_numpy(float)
            gap = guide_gap_m(dataset.line, x, tr["y_m"].to_numpy(float), yaw, length, float(height[fid]))
            half = 0.5 * length * np.abs(np.cos(yaw))
            for conv in dataset.line.conveyors:
                on = (x - half > conv.x_start_m + EDGE_M) & (x + half < conv.x_end_m - EDGE_M)
                if on.sum() < 5:
                    continue
                log = run.belts[run.belts["conveyor_id"] == conv.id]
                stretch = np.floor((x - conv.x_start_m) / STRETCH_M).astype(int)
                for k in np.unique(stretch[on]):
                    m = on & (stretch == k)
                    if m.sum() < 5 or np.ptp(t[m]) < 0.2:
                        continue
                    g = float(np.median(gap[m]))
                    if GUIDE_TOUCH_M[0] <= g <= GUIDE_TOUCH_M[1]:
                        continue
                    belt = log[(log["t_s"] >= t[m][0]) & (log["t_s"] <= t[m][-1])]["speed_mps"]
                    if belt.empty:
                        continue
                    rows.append({"run_id": run.id, "fish_id": fid, "conveyor_id": conv.id,
                                 "x_m": conv.x_start_m + (k + 0.5) * STRETCH_M,
                                 "slip_mps": float(belt.mean()) - float(np.polyfit(t[m], x[m], 1)[0]),
                                 "touching": float(g < GUIDE_TOUCH_M[0]), "guide_gap_m": g,
                                 "belt_speed_mps": float(belt.mean()), "hours_post_mortem": float(hours[fid]),
                                 "weight_kg": float(fish.loc[fid, "weight_kg"]), "length_m": length,
                                 "heading": float(np.median(np.cos(yaw[m]))),
                                 "t_in_run_s": float(np.mean(t[m]))})
    cols = ["run_id", "fish_id", "conveyor_id", "x_m", "slip_mps", "touching", "guide_gap_m", "belt_speed_mps",
            "hours_post_mortem", "weight_kg", "length_m", "heading", "t_in_run_s"]
    return pd.DataFrame(rows, columns=cols)
