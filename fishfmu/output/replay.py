"""The 3D replay of a run: one self-contained HTML file that plays the run in a browser, offline.

The page (``fishfmu/output/web/``: a template, a style sheet, our own small WebGL2 renderer
``render.js`` and the player ``replay.js``; no third-party code) gets everything it draws inlined:
the line from ``run/dataset.toml``, each fish's five bodies from ``poses.npz`` (recorded by
``fishfmu run --replay`` at 25 Hz), belt travel integrated from ``belts.csv``, the photo-eyes'
blocked intervals, and optionally a measured run drawn with the simulated one: each tracked fish as
a translucent "ghost" of its size at its tracked mid-point and heading, and the measured photo-eye
states (:func:`write_compare_replay`, one page per run of ``fishfmu compare``).

Packing. Every number is quantised to an integer (positions in mm, quaternion parts in 1/4096,
times in ms), delta-coded along time, zig-zag coded (small negative -> small positive) and split
into byte planes, so that slow or resting fish give long runs of zeros; all arrays are then
deflated together and base64-coded into the page, which inflates them with the browser's own
``DecompressionStream``.  A fish waiting to be dropped or gone from the line holds its nearest
visible pose, which costs nothing after deflate.  A 60 s, 50-fish run gives a page of about
0.5 MB, 0.7 MB if all 50 fish move for the whole minute (docs/replay.md).

Devices (``[[line.devices]]``: gates, pushers, diverters).  The header holds each device's triangles
in its body's frame and its motion (``origin_m``, ``axis``, ``travel``, ``rotates``: the parameters of
:meth:`plant.contract.devices.DeviceShape.pose`), and the array ``device_p`` (D, F) each device's
position p (0 home .. 1 end) at each frame, in 1/10000; the page turns p into the body's pose as the
plant does.  A record without device positions (a line without devices, an older poses.npz) draws
the devices at home.

>>> codec_round_trip(np.array([[0, 5, -3, 70000, 69990]]))
True
"""

from __future__ import annotations

import base64
import json
import math
import re
import zipfile
import zlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from plant.errors import InputError
from plant.fish.fish_data import length_regressions
from plant.contract.devices import CHUTE_DEPTH_M, device_shapes, guide_openings, pusher_openings
from plant.contract.line import Line
from plant.contract.parts import part_triangles
from plant.contract.measured import Run, read_dataset
from plant.sim.state import FishStatus

from fishfmu.output.atomic import write_text_atomic

POS_UNIT_M = 0.001
"""Position quantum: 1 mm, below what a screen shows of a 6 m line (and the tracking noise)."""
QUAT_UNIT = 1.0 / 4096
"""Quaternion quantum: about 0.03 degrees of rotation."""
TIME_UNIT_S = 0.001
ANGLE_UNIT_RAD = 1e-4
DEVICE_P_UNIT = 1e-4
"""Device position quantum: a 0.35 m gate flap's far edge within 0.04 mm."""
MAX_FRAME_RATE_HZ = 30.0
"""Poses recorded faster than this are thinned: a browser interpolates between frames anyway."""


# ------------------------------------------------------------------------------------- the codec
def encode_ints(values: np.ndarray) -> bytes:
    """Rows of integers -> delta along each row, zig-zag, 4 byte planes (lowest byte of every value
    first).  The page's ``decodeInts`` undoes it; values must fit in int32 (deltas may wrap)."""
    v = np.ascontiguousarray(np.atleast_2d(values), dtype=np.int64)
    if v.size and (v.min() < -2**31 or v.max() >= 2**31):
        raise ValueError("value outside int32")
    d = np.diff(v, axis=1, prepend=0).astype(np.int32)          # int32 wrap-around is undone in the page
    z = ((d.astype(np.int64) << 1) ^ (d.astype(np.int64) >> 31)).astype(np.uint32)
    return z.astype("<u4").reshape(-1).view(np.uint8).reshape(-1, 4).T.tobytes()


def decode_ints(data: bytes, rows: int, cols: int) -> np.ndarray:
    """The inverse of :func:`encode_ints` (for tests; the page has its own in JavaScript)."""
    planes = np.frombuffer(data, np.uint8).reshape(4, rows * cols).astype(np.uint32)
    z = planes[0] | planes[1] << 8 | planes[2] << 16 | planes[3] << 24
    d = ((z >> 1).astype(np.int64) ^ -(z & 1).astype(np.int64)).reshape(rows, cols)
    return np.cumsum(d, axis=1).astype(np.int32).astype(np.int64)   # int32 wrap-around, as in the page


def codec_round_trip(values: np.ndarray) -> bool:
    v = np.atleast_2d(values)
    return bool(np.array_equal(decode_ints(encode_ints(v), *v.shape), v))


@dataclass
class Packer:
    """Arrays of one page: their bytes back to back, and where each one is (the page's index)."""

    chunks: list[bytes]
    index: dict[str, dict[str, Any]]

    def add(self, name: str, values: np.ndarray, unit: float = 1.0) -> None:
        """Add ``values`` (rows along time) quantised to ``unit``: the page reads ``int * unit``."""
        v = np.atleast_2d(np.asarray(values, dtype=np.float64))
        q = np.rint(v / unit).astype(np.int64)
        offset = sum(len(c) for c in self.chunks)
        self.chunks.append(encode_ints(q))
        self.index[name] = {"offset": offset, "rows": int(v.shape[0]), "cols": int(v.shape[1]), "unit": unit}

    def blob(self) -> str:
        return base64.b64encode(zlib.compress(b"".join(self.chunks), 9)).decode("ascii")


def unpack(header: dict[str, Any], blob: str) -> dict[str, np.ndarray]:
    """Every array of a page as floats, shaped (rows, cols): what the page decodes."""
    raw = zlib.decompress(base64.b64decode(blob))
    out = {}
    for name, e in header["arrays"].items():
        n = e["rows"] * e["cols"] * 4
        out[name] = decode_ints(raw[e["offset"]:e["offset"] + n], e["rows"], e["cols"]) * e["unit"]
    return out


# -------------------------------------------------------------------------------- what is drawn
def hold_hidden(values: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """(F, ...) values with the frames where ``visible`` (F,) is false replaced by the nearest visible
    frame's (the earliest one before it is first seen): zero deltas, free after deflate."""
    out = values.copy()
    seen = np.flatnonzero(visible)
    if len(seen) == 0:
        out[:] = 0
        return out
    nearest = seen[np.clip(np.searchsorted(seen, np.arange(len(visible)), side="right") - 1, 0, None)]
    nearest[: seen[0]] = seen[0]
    return out[nearest]


def continuous_quaternions(quat: np.ndarray) -> np.ndarray:
    """(F, B, 4) with each frame's sign chosen nearest the previous frame (q and -q are one rotation):
    small deltas, and the page can interpolate component-wise."""
    q = quat.astype(np.float64).copy()
    for k in range(1, len(q)):
        flip = np.einsum("bi,bi->b", q[k], q[k - 1]) < 0
        q[k, flip] *= -1
    return q


def belt_travel(belts: pd.DataFrame, conveyor_ids: list[str], t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(travel_m, speed_mps), each (C, F): how far each belt's surface has moved by each frame time
    (the trapezoid integral of the drive log) and its speed then."""
    travel = np.zeros((len(conveyor_ids), len(t_s)))
    speed = np.zeros_like(travel)
    for i, c in enumerate(conveyor_ids):
        log = belts[belts["conveyor_id"] == c].sort_values("t_s")
        if log.empty:
            continue
        t, v = log["t_s"].to_numpy(float), log["speed_mps"].to_numpy(float)
        s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]) + v[0] * t[0]
        travel[i] = np.interp(t_s, t, s)
        speed[i] = np.interp(t_s, t, v)
    return travel, speed


def fish_colours(n: int) -> list[list[float]]:
    """Distinct hues (golden-angle steps) so that a person can follow one fish down the line."""
    out = []
    for i in range(n):
        h = (0.08 + 0.618034 * i) % 1.0
        r, g, b = (min(1.0, max(0.0, abs(((h * 6 + k) % 6) - 3) - 1)) for k in (0, 4, 2))
        out.append([round(0.25 + 0.6 * r, 3), round(0.25 + 0.6 * g, 3), round(0.25 + 0.6 * b, 3)])
    return out


def frame_stride(t_s: np.ndarray) -> int:
    if len(t_s) < 2:
        return 1
    rate_hz = (len(t_s) - 1) / max(t_s[-1] - t_s[0], 1e-9)
    return max(1, math.ceil(rate_hz / MAX_FRAME_RATE_HZ - 1e-6))


def _photoeye_intervals(photoeyes: pd.DataFrame, ids: list[str]) -> dict[str, list[list[float]]]:
    return {p: [[round(float(a), 3), round(float(b), 3)]
                for a, b in photoeyes.loc[photoeyes["sensor_id"] == p, ["t_on_s", "t_off_s"]].to_numpy()]
            for p in ids}


Measured = Run | tuple[pd.DataFrame, pd.DataFrame] | tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]
"""A measured run to draw with the simulated one: a :class:`plant.contract.measured.Run`, or its ``(fish, tracks)``
or ``(fish, tracks, photoeyes)`` tables in the measured-data format."""


def _fish_size(sizes: pd.DataFrame, fid: Any) -> tuple[float, float, float]:
    """(length, height, width) of a measured fish; fish.csv may leave height and width empty (then
    the length regressions of Table I, as the reader fills them)."""
    length_m = float(sizes.at[fid, "length_m"]) if fid in sizes.index else 0.6
    reg = length_regressions()
    out = [length_m]
    for col, fit, ratio in (("height_m", reg.height_m, 0.22), ("width_m", reg.width_m, 0.11)):
        v = sizes.at[fid, col] if fid in sizes.index and col in sizes.columns else float("nan")
        v = float(v) if pd.notna(v) and float(v) > 0 else float(fit(length_m))
        out.append(v if math.isfinite(v) and v > 0.02 * length_m else ratio * length_m)
    return out[0], out[1], out[2]


def _add_measured(packer: Packer, measured: Measured, photoeye_ids: list[str]) -> dict[str, Any]:
    """Pack a measured run's tracks (sorted by fish, then time) and describe its fish and photo-eyes."""
    if isinstance(measured, Run):
        fish, tracks, photoeyes = measured.fish, measured.tracks, measured.photoeyes
    else:
        fish, tracks, photoeyes = (*measured, None) if len(measured) == 2 else measured
    sizes = fish.set_index("fish_id")
    ordered = tracks.sort_values(["fish_id", "t_s"], kind="stable")
    entries, start = [], 0
    for fid, rows in ordered.groupby("fish_id", sort=False):
        length_m, height_m, width_m = _fish_size(sizes, fid)
        entries.append({"id": str(fid), "length_m": round(length_m, 4), "height_m": round(height_m, 4),
                        "width_m": round(width_m, 4), "start": start, "count": len(rows)})
        start += len(rows)
    yaw = ordered["yaw_rad"].to_numpy(float)
    packer.add("m_t", ordered["t_s"].to_numpy(float), TIME_UNIT_S)
    packer.add("m_xy", ordered[["x_m", "y_m"]].to_numpy(float).T, POS_UNIT_M)
    packer.add("m_yaw", np.unwrap(yaw) if len(yaw) else yaw, ANGLE_UNIT_RAD)
    ends = [float(ordered["t_s"].max())] if len(ordered) else [0.0]
    if photoeyes is not None and len(photoeyes):
        ends.append(float(photoeyes["t_off_s"].max()))
    return {"fish": entries, "t_end_s": max(ends),
            "photoeyes": None if photoeyes is None else _photoeye_intervals(photoeyes, photoeye_ids)}


def scene(run_dir: Path, measured: Measured | None = None) -> tuple[dict[str, Any], str]:
    """The page's header (line, fish, photo-eyes, array index) and its packed arrays (base64), for a
    ``fishfmu run --replay`` folder."""
    poses_file = run_dir / "poses.npz"
    if not poses_file.exists():
        raise InputError("no poses.npz: run the scenario with --replay to record the bodies' poses", file=run_dir)
    data = read_dataset(run_dir / "run", check_physics=False)  # written by this program (fish not yet dropped too)
    p = read_poses(poses_file)
    if len(p["t_s"]) == 0:
        raise InputError("poses.npz holds no frames: the run stopped before its first pose sample", file=poses_file)
    return build_scene(data.line, data.name, data.runs[0], p, measured)


POSE_ARRAYS = {"t_s": 1, "pos": 3, "quat": 3, "status": 2, "fish_id": 1, "body_fish": 1, "section_body": 1,
               "section_x": 1, "section_half_height": 1, "section_half_width": 1}
"""The arrays of poses.npz and their number of dimensions (:func:`plant.sim.recorder.pose_record`)."""
DEVICE_ARRAYS = ("device_id", "device_position")
"""The arrays a record of a line with devices has besides (both or neither)."""


def read_poses(path: Path) -> dict[str, np.ndarray]:
    """poses.npz, checked: a readable archive (no pickled objects) with every array, shapes and indices
    that agree, finite times and outlines (poses are NaN while a fish is off the line); anything else is
    bad input naming the file."""
    def bad(what: str) -> InputError:
        return InputError(f"{what}; record it again with `fishfmu run --replay`", file=path)

    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [k for k in POSE_ARRAYS if k not in npz.files]
            if missing:
                raise bad(f"not a pose record: no array {', '.join(missing)}")
            p = {k: npz[k] for k in POSE_ARRAYS}
            present = [k for k in DEVICE_ARRAYS if k in npz.files]
            if len(present) == 1:
                raise bad(f"array {present[0]} without {next(k for k in DEVICE_ARRAYS if k not in present)}")
            p |= {k: npz[k] for k in present}
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise bad(f"not a readable pose record (corrupt or not a .npz file: {type(exc).__name__}: "
                  f"{str(exc).strip() or 'no detail'})") from None
    for k, ndim in POSE_ARRAYS.items():
        if p[k].ndim != ndim:
            raise bad(f"array {k} has {p[k].ndim} dimensions, expected {ndim}")
    if p["fish_id"].dtype.kind not in "US":
        raise bad(f"array fish_id holds {p['fish_id'].dtype}, expected text")
    for k in POSE_ARRAYS:
        if k != "fish_id" and p[k].dtype.kind not in "iuf":
            raise bad(f"array {k} holds {p[k].dtype}, expected numbers")
    n_t, n_fish, n_bodies = len(p["t_s"]), len(p["fish_id"]), len(p["body_fish"])
    shapes = {"pos": (n_t, n_bodies, 3), "quat": (n_t, n_bodies, 4), "status": (n_t, n_fish)}
    for k, shape in shapes.items():
        if p[k].shape != shape:
            raise bad(f"array {k} has shape {p[k].shape}, expected {shape} (frames, bodies or fish do not agree)")
    n_sec = len(p["section_body"])
    for k in ("section_x", "section_half_height", "section_half_width"):
        if len(p[k]) != n_sec:
            raise bad(f"array {k} has {len(p[k])} entries, section_body {n_sec}")
    if n_bodies and (p["body_fish"].min() < 0 or p["body_fish"].max() >= n_fish):
        raise bad("array body_fish names a fish that is not in fish_id")
    if n_sec and (p["section_body"].min() < 0 or p["section_body"].max() >= n_bodies):
        raise bad("array section_body names a body that is not in body_fish")
    for k in ("t_s", "section_x", "section_half_height", "section_half_width"):  # poses are NaN off the line
        if not np.all(np.isfinite(p[k])):
            raise bad(f"array {k} holds a value that is not a finite number")
    if n_t > 1 and np.any(np.diff(p["t_s"]) <= 0):
        raise bad("array t_s does not increase")
    if "device_id" in p:  # devices: each one's position p at each frame
        ids, position = p["device_id"], p["device_position"]
        if ids.ndim != 1 or ids.dtype.kind not in "US":
            raise bad(f"array device_id holds {ids.ndim}-dimensional {ids.dtype}, expected text (one per device)")
        if position.dtype.kind not in "iuf" or position.shape != (n_t, len(ids)):
            raise bad(f"array device_position has shape {position.shape} of {position.dtype}, expected numbers of "
                      f"shape {(n_t, len(ids))} (frames or devices do not agree)")
        if not np.all(np.isfinite(position)):
            raise bad("array device_position holds a value that is not a finite number")
    return p


def build_scene(line: Line, name: str, run: Run, p: dict[str, np.ndarray], measured: Measured | None = None,
                run_id: str | None = None) -> tuple[dict[str, Any], str]:
    """The page's header and packed arrays from a simulated ``run`` (its belts and photo-eyes tables)
    and its body poses ``p`` (the arrays of poses.npz: :func:`plant.sim.recorder.pose_record`)."""
    if len(p["t_s"]) == 0:
        raise InputError(f"run {run.id}: no pose frames recorded")
    stride = frame_stride(p["t_s"])
    t_s, pos, quat, status = p["t_s"][::stride], p["pos"][::stride], p["quat"][::stride], p["status"][::stride]
    n_fish, n_bodies = status.shape[1], pos.shape[1]
    body_fish = p["body_fish"]
    visible = status[:, body_fish] == FishStatus.ON_LINE            # (F, B)
    pos = np.stack([hold_hidden(pos[:, b], visible[:, b]) for b in range(n_bodies)], axis=1)
    quat = np.stack([hold_hidden(quat[:, b], visible[:, b]) for b in range(n_bodies)], axis=1)
    quat = continuous_quaternions(quat)
    conveyor_ids = [c.id for c in line.conveyors]
    travel_m, speed_mps = belt_travel(run.belts, conveyor_ids, t_s)

    packer = Packer([], {})
    packer.add("t", t_s, TIME_UNIT_S)
    # (B*3, F) and (B*4, F): one row per body coordinate, so each row is one smooth signal in time
    packer.add("pos", pos.transpose(1, 2, 0).reshape(n_bodies * 3, -1), POS_UNIT_M)
    packer.add("quat", quat.transpose(1, 2, 0).reshape(n_bodies * 4, -1), QUAT_UNIT)
    packer.add("status", status.T.astype(np.int64))
    packer.add("belt_travel", travel_m, POS_UNIT_M)
    packer.add("belt_speed", speed_mps, POS_UNIT_M)
    header = line_header(line, name, run_id or run.id, p, packer)
    if header["devices"]:
        packer.add("device_p", device_positions(line, p, stride), DEVICE_P_UNIT)
    header |= {"duration_s": float(t_s[-1]) if len(t_s) else 0.0,
               "photoeyes": _photoeye_intervals(run.photoeyes, [pe.id for pe in line.photoeyes])}
    if measured is not None:
        header["measured"] = _add_measured(packer, measured, [pe.id for pe in line.photoeyes])
        header["duration_s"] = max(header["duration_s"], header["measured"]["t_end_s"])
    header["arrays"] = packer.index
    return header, packer.blob()


def line_header(line: Line, name: str, run_id: str, p: dict[str, np.ndarray], packer: Packer) -> dict[str, Any]:
    """What a page draws that does not move: the line, its parts and devices, the fish (ids, colours) and their
    bodies' outlines (packed into ``packer``); a recorded page adds its frames, ``serve --live`` streams them."""
    order = np.lexsort((p["section_x"], p["section_body"]))          # by body, then tail to head
    packer.add("sec_body", p["section_body"][order].astype(np.int64))
    for key in ("section_x", "section_half_height", "section_half_width"):
        packer.add(key.replace("section", "sec"), p[key][order], 1e-4)
    return {
        "version": 1, "name": name, "run_id": run_id, "duration_s": 0.0,
        "line": line.model_dump(),
        "parts": _part_triangles(line), "devices": _devices(line),
        "guide_openings": [[side, round(x0, 6), round(x1, 6)] for side, x0, x1 in guide_openings(line)],
        "chutes": [[side, round(x0, 6), round(x1, 6), CHUTE_DEPTH_M] for side, x0, x1 in pusher_openings(line)],
        "fish": {"ids": [str(f) for f in p["fish_id"]], "colours": fish_colours(len(p["fish_id"])),
                 "body_fish": p["body_fish"].astype(int).tolist()},
        "photoeyes": {}, "measured": None,
    }


def _part_triangles(line: Line) -> list[float]:
    """The line's fixed parts as one flat list of triangle corners (x, y, z, mm-rounded), to draw."""
    pts, trigs = part_triangles(line)
    return [round(c, 4) for t in trigs for i in t for c in pts[i]]


def _devices(line: Line) -> list[dict[str, Any]]:
    """Each device of the line to draw: its triangles' corners in its body's frame (flat x, y, z, mm-rounded like
    the parts') and the parameters of its motion (:meth:`plant.contract.devices.DeviceShape.pose`)."""
    return [{"id": s.device.id, "kind": s.device.kind, "origin_m": [round(float(v), 6) for v in s.origin_m],
             "axis": [float(v) for v in s.axis], "travel": round(float(s.travel), 9), "rotates": s.rotates,
             "triangles": [round(float(c), 4) for t in s.triangles for i in t for c in s.points_m[i]]}
            for s in device_shapes(line)]


def device_positions(line: Line, p: dict[str, np.ndarray], stride: int = 1) -> np.ndarray:
    """(D, F) each line device's recorded position p at each (thinned) frame, in the line's order; 0 (home) for a
    device the record does not hold (one without device positions)."""
    n_frames = len(p["t_s"][::stride])
    out = np.zeros((len(line.devices), n_frames))
    recorded = [str(i) for i in p.get("device_id", [])]
    for d, device in enumerate(line.devices):
        if device.id in recorded:
            out[d] = np.clip(p["device_position"][::stride, recorded.index(device.id)], 0.0, 1.0)
    return out


def _asset(name: str) -> str:
    return resources.files("fishfmu.output").joinpath("web", name).read_text(encoding="utf-8")


def render_html(header: dict[str, Any], blob: str) -> str:
    """The template with the style, the script, the header and the data inlined."""
    # "<" as \u003c: no "</script>" or "<!--" inside the script element, whatever the names say
    header_json = json.dumps(header, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    title = f"fishfmu replay: {header['name']} / {header['run_id']}"
    parts = {"__TITLE__": title.replace("&", "&amp;").replace("<", "&lt;"), "/*__STYLE__*/": _asset("replay.css"),
             "/*__HEADER__*/": header_json, "/*__DATA__*/": blob, "/*__RENDER__*/": _asset("render.js"),
             "/*__SCRIPT__*/": _asset("replay.js"),
             "/*__LIVE__*/": _asset("live.js") if header.get("live") else ""}  # a recorded page fetches nothing
    template = _asset("replay.html")
    missing = [m for m in parts if template.count(m) != 1]
    if missing:
        raise RuntimeError(f"replay template needs each of {missing} once")
    # one pass over the template: text already inlined is never searched for markers
    return re.sub("|".join(map(re.escape, parts)), lambda m: parts[m.group(0)], template)


def write_page(header: dict[str, Any], blob: str, out: Path) -> Path:
    """The page, written atomically (a reader never sees half a page)."""
    html = render_html(header, blob)
    write_text_atomic(out, html)  # recorded in the folder's manifest (fishfmu.output.manifest)
    return out


def write_replay(run_dir: str | Path, out_file: str | Path | None = None, measured: Measured | None = None) -> Path:
    """Write the run in ``run_dir`` (a ``fishfmu run --replay`` folder) as one HTML page that replays it
    in 3D; returns its path (``run_dir/replay.html`` unless ``out_file``).

    ``measured``: optionally a measured run (a :class:`plant.contract.measured.Run`, or its ``(fish, tracks)``
    or ``(fish, tracks, photoeyes)`` tables) drawn with the simulated fish: each tracked fish as a
    translucent ghost, its outline ``length_m`` x ``height_m`` seen from above (a salmon lies on its
    side) and ``width_m`` thick, at its tracked mid-point and heading; hidden before its first and
    after its last track sample and in gaps of the tracking longer than 0.5 s.  Times are those of
    each run's own start, so a simulation of the measured batch lines up with it.
    """
    run_dir = Path(run_dir)
    out = Path(out_file) if out_file is not None else run_dir / "replay.html"
    header, blob = scene(run_dir, measured)
    return write_page(header, blob, out)


def write_compare_replay(line: Line, name: str, measured: Run, simulated: Run, poses: dict[str, np.ndarray],
                         out_file: str | Path) -> Path:
    """One page of ``fishfmu compare``: the re-simulation of a measured run (its tables ``simulated`` and
    the body poses it recorded, ``SimulatedRun.poses``) with the measured run drawn over it as
    ghosts, and the measured photo-eye states; the page can show either or both."""
    header, blob = build_scene(line, name, simulated, poses, measured, run_id=measured.id)
    return write_page(header, blob, Path(out_file))


def read_header(html_file: str | Path) -> tuple[dict[str, Any], str]:
    """The header and the packed data of a replay page (for tests and for reading a page back)."""
    html = Path(html_file).read_text(encoding="utf-8")
    header = html.split('<script type="application/json" id="replay-header">', 1)[1].split("</script>", 1)[0]
    blob = html.split('<script type="text/plain" id="replay-data">', 1)[1].split("</script>", 1)[0]
    return json.loads(header), blob.strip()
