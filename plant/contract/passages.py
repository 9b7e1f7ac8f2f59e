"""When each fish passes a photo-eye beam, from tracks and photo-eye intervals (contracts/kpis.md).

One implementation for measured and simulated runs: anything with the tables of
contracts/measured-data.md (``fish``, ``tracks``, ``photoeyes``, ``belts``) will do.

**From tracks.** Seen from above, a dead salmon lying on its side is a rectangle of its length
along its heading and its height across, so its extent along x from its mid-point is
``ext = (L/2)|cos yaw| + (H/2)|sin yaw|`` (H from the length regression where fish.csv has
none).  Its passage starts at the *first* time its front ``x + ext`` reaches the beam and ends at
the *last* time its rear ``x - ext`` reaches it (so tracking noise at the beam cannot split a
passage), each interpolated linearly between the two samples around the crossing.  Tracks are
irregular; a crossing between samples more than ``max_gap_s`` apart is *not trusted*.  A fish
whose track begins or ends inside the beam has one end missing: it is put at the fish's own
extent travelled at belt speed from the end that is known (not trusted either).

**Photo-eye intervals** of the beam are first merged into blocked periods: a clear moment
shorter than ``min_gap_m`` along the belt is flicker (and could never make a fish singulated).
Then, for every passage from tracks, the periods it overlaps form a hull ``[on, off]``:

- a trusted time is clipped into the hull (the beam itself says when it was blocked; for a fish
  alone in a period this is exactly that period, for fish sharing one only its outer edges);
- a time not trusted is replaced by the hull's edge.

A passage that spans a clear moment of the beam keeps it covered: a low beam does not see a fish
riding on top of another, the camera does, so the tracks win there (conservative: it can only
take singulated fish away, never add one).

A fish with no passage in its track (track ends before the beam, no track at all) can only be
found by the beam.  A period blocked for a length ``l`` (duration x belt speed) holds
``round(l / median fish length)`` fish (at least 1, but 0 for a pulse shorter than half the
smallest fish's height).  Fish a period holds beyond those tracked through it are added as
estimated passages (``fish_id`` None, ``source`` "photoeye"), periods with no tracked fish
first, in time order, but never more than the fish not otherwise accounted for.  Fish still
unaccounted for never passed: they are *lost*.

``source`` of a passage: "tracks" (no photo-eye overlap), "tracks+photoeye" (times clipped or
completed by the beam), "tracks+estimate" (an end not trusted and no beam to fix it),
"photoeye" (fish count estimated from the beam).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
import pandas as pd

from plant.errors import InputError
from plant.fish.fish_data import length_regressions
from plant.contract.line import KpiSettings, Line

MAX_TRACK_GAP_S = 0.5
"""Longest gap between two track samples that a crossing may be interpolated across (assumption:
at the belt speeds of a singulation line a fish moves well under its own length in 0.5 s)."""

SpeedFn = Callable[[np.ndarray], np.ndarray]

PASSAGE_COLUMNS = ["fish_id", "t_start_s", "t_end_s", "source"]


class RunTables(Protocol):
    """What the KPIs need of a run: the four tables of contracts/measured-data.md."""

    fish: pd.DataFrame
    tracks: pd.DataFrame
    photoeyes: pd.DataFrame
    belts: pd.DataFrame


def belt_speed_fn(run: RunTables, conveyor_id: str) -> SpeedFn:
    """Belt speed (encoder ``speed_mps``) of one conveyor at any times, linear between log samples.

    >>> class R: belts = pd.DataFrame({"t_s": [0.0, 1.0], "conveyor_id": ["c1", "c1"], "speed_mps": [0.0, 2.0]})
    >>> float(belt_speed_fn(R, "c1")(np.array([0.25]))[0])
    0.5
    """
    log = run.belts[run.belts["conveyor_id"] == conveyor_id]
    if log.empty:
        raise InputError(f"no samples for conveyor '{conveyor_id}': the gaps at the outfeed need its belt speed",
                         file=_file(run, "belts.csv"))
    order = np.argsort(log["t_s"].to_numpy(float), kind="stable")
    t = log["t_s"].to_numpy(float)[order]
    v = log["speed_mps"].to_numpy(float)[order]
    return lambda times: np.interp(np.asarray(times, dtype=float), t, v)


def _file(run: object, name: str) -> str:
    path = getattr(run, "path", None)
    return str(path / name) if path is not None else name


def fish_extent_lengths(fish: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(length_m, height_m) per fish, height from the length regression where it is empty."""
    length = fish["length_m"].to_numpy(float)
    height = fish["height_m"].to_numpy(float) if "height_m" in fish else np.full(len(fish), np.nan)
    return length, np.where(np.isnan(height), length_regressions().height_m(length), height)


def _sorted_tracks(run: RunTables) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(fish index, t_s, x_m, ext_m) of every sample with a known fish, sorted by fish then time."""
    tr = run.tracks
    code = pd.Categorical(tr["fish_id"], categories=run.fish["fish_id"]).codes.astype(np.int64)
    keep = code >= 0
    code, t = code[keep], tr["t_s"].to_numpy(float)[keep]
    x, yaw = tr["x_m"].to_numpy(float)[keep], tr["yaw_rad"].to_numpy(float)[keep]
    order = np.lexsort((t, code))
    code, t, x, yaw = code[order], t[order], x[order], yaw[order]
    length, height = fish_extent_lengths(run.fish)
    ext = 0.5 * length[code] * np.abs(np.cos(yaw)) + 0.5 * height[code] * np.abs(np.sin(yaw))
    return code, t, x, ext


def _crossings(code: np.ndarray, t: np.ndarray, value: np.ndarray, level: float, n_fish: int,
               last: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per fish: (time, sample gap, segment index) of its first (or last) upward crossing of ``level``.

    A crossing is a pair of consecutive samples of one fish with ``value`` below, then at or above
    ``level``; its time is interpolated linearly.  NaN / -1 where the fish has none.
    """
    seg = np.flatnonzero((code[1:] == code[:-1]) & (value[:-1] < level) & (value[1:] >= level))
    t_out, gap_out, seg_out = np.full(n_fish, np.nan), np.full(n_fish, np.nan), np.full(n_fish, -1)
    if len(seg) == 0:
        return t_out, gap_out, seg_out
    if last:
        seg = seg[::-1]
    _, first = np.unique(code[seg], return_index=True)
    seg = seg[first]
    dt = t[seg + 1] - t[seg]
    frac = (level - value[seg]) / (value[seg + 1] - value[seg])
    who = code[seg]
    t_out[who], gap_out[who], seg_out[who] = t[seg] + frac * dt, dt, seg
    return t_out, gap_out, seg_out


def arrival_times(run: RunTables, line: Line, max_gap_s: float = MAX_TRACK_GAP_S) -> pd.DataFrame:
    """When each fish's front first reaches each photo-eye beam, from tracks.

    Columns ``fish_id, sensor_id, t_s, status``; status "ok", "gap" (the crossing fell in a
    tracking gap longer than ``max_gap_s``: t_s NaN), "before_track" (the track starts with the
    front already past the beam: t_s NaN) or "not_reached" (t_s NaN).
    """
    n = len(run.fish)
    code, t, x, ext = _sorted_tracks(run)
    first = np.unique(code, return_index=True)
    first_front = np.full(n, -np.inf)
    first_front[first[0]] = (x + ext)[first[1]]
    frames = []
    for pe in line.photoeyes:
        t_cross, gap, _ = _crossings(code, t, x + ext, pe.x_m, n)
        status = np.where(~np.isnan(t_cross), np.where(gap <= max_gap_s, "ok", "gap"),
                          np.where(first_front >= pe.x_m, "before_track", "not_reached"))
        frames.append(pd.DataFrame({"fish_id": run.fish["fish_id"].to_numpy(), "sensor_id": pe.id,
                                    "t_s": np.where(status == "ok", t_cross, np.nan), "status": status}))
    cols = ["fish_id", "sensor_id", "t_s", "status"]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=cols)


def track_passages(run: RunTables, x_beam_m: float, speed_fn: SpeedFn,
                   max_gap_s: float = MAX_TRACK_GAP_S) -> pd.DataFrame:
    """Passages of the beam at ``x_beam_m`` from tracks alone, one row per fish that has one.

    Columns ``fish_id, t_start_s, t_end_s, start_trusted, end_trusted`` (see the module doc).
    """
    n = len(run.fish)
    code, t, x, ext = _sorted_tracks(run)
    s, s_gap, s_seg = _crossings(code, t, x + ext, x_beam_m, n)
    e, e_gap, e_seg = _crossings(code, t, x - ext, x_beam_m, n, last=True)
    has = ~np.isnan(s) | ~np.isnan(e)
    s_trusted, e_trusted = s_gap <= max_gap_s, e_gap <= max_gap_s
    # one end missing (track begins or ends inside the beam): the fish's own extent at belt speed
    only_s, only_e = ~np.isnan(s) & np.isnan(e), np.isnan(s) & ~np.isnan(e)
    if only_s.any():
        e[only_s] = s[only_s] + 2 * ext[s_seg[only_s]] / np.maximum(speed_fn(s[only_s]), 1e-3)
    if only_e.any():
        s[only_e] = e[only_e] - 2 * ext[e_seg[only_e]] / np.maximum(speed_fn(e[only_e]), 1e-3)
    e = np.maximum(e, s)
    return pd.DataFrame({"fish_id": run.fish["fish_id"].to_numpy()[has], "t_start_s": s[has], "t_end_s": e[has],
                         "start_trusted": s_trusted[has], "end_trusted": e_trusted[has]})


def blocked_periods(photoeyes: pd.DataFrame, sensor_id: str, speed_fn: SpeedFn, min_gap_m: float) -> pd.DataFrame:
    """The sensor's blocked intervals, merged across clear moments shorter than ``min_gap_m`` of belt.

    >>> pe = pd.DataFrame({"sensor_id": ["a", "a", "a"], "t_on_s": [0.0, 0.52, 2.0], "t_off_s": [0.5, 1.0, 2.5]})
    >>> blocked_periods(pe, "a", lambda t: np.ones_like(t), 0.05).to_numpy().tolist()
    [[0.0, 1.0], [2.0, 2.5]]
    """
    iv = photoeyes[photoeyes["sensor_id"] == sensor_id].sort_values("t_on_s", kind="stable")
    on, off = iv["t_on_s"].to_numpy(float), iv["t_off_s"].to_numpy(float)
    if len(on) == 0:
        return pd.DataFrame({"t_on_s": on, "t_off_s": off})
    off_so_far = np.maximum.accumulate(off)
    clear_s = on[1:] - off_so_far[:-1]
    clear_m = clear_s * speed_fn(0.5 * (on[1:] + off_so_far[:-1]))
    new = np.r_[True, (clear_s > 0) & (clear_m >= min_gap_m)]
    return pd.DataFrame({"t_on_s": on[new], "t_off_s": np.maximum.reduceat(off, np.flatnonzero(new))})


def _fish_in_period(length_m: np.ndarray, height_m: np.ndarray, blocked_m: np.ndarray) -> np.ndarray:
    """How many fish a blocked length holds: against the batch's median length, 0 for a short pulse."""
    n = np.floor(blocked_m / np.median(length_m) + 0.5).astype(int)
    return np.where(blocked_m < 0.5 * np.min(height_m), 0, np.maximum(n, 1))


def passages(run: RunTables, line: Line, kpi: KpiSettings, max_gap_s: float = MAX_TRACK_GAP_S) -> pd.DataFrame:
    """Every passage of the outfeed beam (``kpi.outfeed_photoeye``), sorted by start (module doc).

    Columns ``fish_id`` (None for a fish estimated from the beam), ``t_start_s``, ``t_end_s``, ``source``.
    """
    beam = line.photoeye(kpi.outfeed_photoeye)
    speed = belt_speed_fn(run, line.conveyor_at(beam.x_m).id)
    tp = track_passages(run, beam.x_m, speed, max_gap_s)
    periods = blocked_periods(run.photoeyes, beam.id, speed, kpi.min_gap_m)
    on, off = periods["t_on_s"].to_numpy(float), periods["t_off_s"].to_numpy(float)
    s, e = tp["t_start_s"].to_numpy(float, copy=True), tp["t_end_s"].to_numpy(float, copy=True)
    # periods overlapping each passage: a..b (merged periods are disjoint and sorted)
    a = np.searchsorted(off, s, side="right")
    b = np.searchsorted(on, e, side="left") - 1
    hit = a <= b
    if hit.any():
        lo, hi = on[a[hit]], off[b[hit]]
        s_trusted, e_trusted = tp["start_trusted"].to_numpy()[hit], tp["end_trusted"].to_numpy()[hit]
        s[hit] = np.where(s_trusted, np.maximum(s[hit], lo), lo)
        e[hit] = np.where(e_trusted, np.minimum(e[hit], hi), hi)
    trusted = tp["start_trusted"].to_numpy(bool) & tp["end_trusted"].to_numpy(bool)
    source = np.where(hit, "tracks+photoeye", np.where(trusted, "tracks", "tracks+estimate"))
    out = pd.DataFrame({"fish_id": tp["fish_id"].to_numpy(object), "t_start_s": s, "t_end_s": e, "source": source})
    # fish the tracks did not see pass, found by the beam
    missing = len(run.fish) - len(out)
    if missing > 0 and len(on):
        tracked = np.zeros(len(on) + 1, dtype=int)
        np.add.at(tracked, a[hit], 1)
        np.add.at(tracked, b[hit] + 1, -1)
        tracked = np.cumsum(tracked)[:-1]
        length, height = fish_extent_lengths(run.fish)
        blocked_m = (off - on) * speed(0.5 * (on + off))
        extra = np.maximum(_fish_in_period(length, height, blocked_m) - tracked, 0)
        order = np.lexsort((on, tracked > 0))  # periods no tracked fish went through first
        take = np.zeros(len(on), dtype=int)
        take[order] = np.diff(np.r_[0, np.minimum(np.cumsum(extra[order]), missing)])
        idx = np.repeat(np.arange(len(on)), take)
        est = pd.DataFrame({"fish_id": np.full(len(idx), None, dtype=object), "t_start_s": on[idx],
                            "t_end_s": off[idx], "source": "photoeye"})
        out = pd.concat([out, est], ignore_index=True) if len(out) else est
    return out.sort_values("t_start_s", kind="stable").reset_index(drop=True)[PASSAGE_COLUMNS]
