"""Reading and writing measured data (contracts/measured-data.md): real runs and simulated ones alike.

A dataset is a folder with ``dataset.toml`` (``[dataset]``, ``[line]``, ``[kpi]``, ``[[runs]]``)
and one folder per run under ``runs/`` with ``fish.csv``, ``tracks.csv``, ``photoeyes.csv`` and
``belts.csv``.  Readers check everything the contract asks and stop at the first problem with
an :class:`~plant.errors.InputError` naming the file and the key, or the row (as a person counts
lines in the file: the header is line 1) and column.  Nothing is dropped silently: extra CSV
columns are kept, extra keys of a ``[[runs]]`` entry are kept in ``Run.extra`` (unless they look
like a misspelt known key), and empty ``height_m``, ``width_m``, ``hours_post_mortem`` in
fish.csv are filled (length regressions, the run's value) and listed in ``Run.filled``;
:func:`write_run` writes those cells empty again, so a round trip gives back the same files.
Blank lines in a CSV are skipped; pandas' usual NaN spellings (empty, NaN, NA, null) are missing values.
A CSV must be UTF-8 (a byte-order mark is allowed) and no row may have more fields than the header (a
trailing comma): the error names the row.

A run must also be physically plausible before anything is simulated (the bounds are the constants
below, each with its reason): fish sizes and weights a salmon can have, drops within the line, between
the guides and above a belt, belt speeds, times from the run's start and within its drive log, every
conveyor in the drive log, and no more than :data:`MAX_RESIM_S` of simulated time per re-simulation.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pydantic
import tomli_w
from pydantic import Field

from plant.errors import InputError
from plant.fish_data import length_regressions
from plant.line import Id, KpiSettings, Line
from plant.validation import MAX_CSV_BYTES, Strict, file_size_checked, read_toml, suggest, validate


@dataclass(frozen=True)
class TableSpec:
    """One CSV of a run: its columns in contract order, which hold text, which may be empty."""

    name: str
    columns: tuple[str, ...]
    text: frozenset[str]
    may_be_empty: frozenset[str] = frozenset()

    @property
    def file(self) -> str:
        return f"{self.name}.csv"


FISH = TableSpec("fish", ("fish_id", "length_m", "weight_kg", "height_m", "width_m", "hours_post_mortem",
                          "drop_t_s", "drop_x_m", "drop_y_m", "drop_yaw_rad", "drop_z_m"),
                 frozenset({"fish_id"}), frozenset({"height_m", "width_m", "hours_post_mortem"}))
TRACKS = TableSpec("tracks", ("t_s", "fish_id", "x_m", "y_m", "yaw_rad"), frozenset({"fish_id"}))
PHOTOEYES = TableSpec("photoeyes", ("sensor_id", "t_on_s", "t_off_s"), frozenset({"sensor_id"}))
BELTS = TableSpec("belts", ("t_s", "conveyor_id", "setpoint_mps", "speed_mps"), frozenset({"conveyor_id"}))
TABLES = (FISH, TRACKS, PHOTOEYES, BELTS)
POSITIVE = ("length_m", "weight_kg", "height_m", "width_m")

# Physical plausibility of a run (checked by :func:`read_run` before anything is simulated).  Generous
# bounds: they catch typing errors, unit mix-ups and corrupt logs, not unusual fish.
LENGTH_RANGE_M = (0.2, 1.5)
"""Salmon length: the population model samples 0.42-0.75 m (Table I: 0.42-0.68 m) and a scenario allows
up to 1.5 m; below 0.2 m the length regressions give bodies thinner than a centimetre."""
WEIGHT_FACTOR = 3.0
"""Weight within this factor of the length-weight regression either way; the fit's residual sd is 6 %
(a factor 3 is 18 sd), the datasets seen so far lie within 0.90-1.15 of it: a mass typed in grams or
pounds, or a length in feet, is caught."""
HEIGHT_PER_LENGTH = (0.05, 0.6)
WIDTH_PER_LENGTH = (0.02, 0.4)
"""Body height and thickness as a fraction of length (Table I: about 0.24-0.29 and 0.10-0.14)."""
MAX_HOURS_POST_MORTEM = 10000.0
"""The same bound as ``hours_post_mortem`` of a ``[[runs]]`` entry (over a year: any real value fits)."""
MAX_DROP_HEIGHT_M = 2.0
"""Height of a fish's lowest point above the belt at release: a fish dropped by hand or from a chute
falls at most this far (a 2 m fall lands at 6.3 m/s; the plant's health check stops at 25 m/s); the
scenario's ``fish.drop_height_m`` has the same bound."""
GUIDE_OVERLAP_M = 0.05
"""How far a dropped fish's footprint (its length along its heading, its height across) may reach into a
side guide: the camera is a few mm off and a fish bends, but a fish cannot lie across the guides (a
0.75 m fish crosswise in a 0.5 m channel is pushed off the line in the first second of the simulation)."""
MAX_BELT_SPEED_MPS = 10.0
"""|setpoint| and |speed| of a belt: singulation belts run at 0.3-2 m/s; 10 m/s is five times that."""
CLOCK_SLACK_S = 1.0
"""Tracks and photo-eye intervals may end this long after the drive log (clocks of different systems)."""
MAX_RESIM_S = 600.0
"""Simulated time of one re-simulation (the last drop, track sample or photo-eye interval, plus 1 s): a
measured batch lasts a minute (25-67 s in the datasets seen so far); 600 s of plant take several minutes
of one core, and diagnose re-simulates every run 10-20 times."""


def empty_table(spec: TableSpec) -> pd.DataFrame:
    """A table with the contract's columns and no rows."""
    return pd.DataFrame({c: pd.Series(dtype=object if c in spec.text else float) for c in spec.columns})


class DatasetInfo(Strict):
    """The ``[dataset]`` table."""

    name: str = Field(min_length=1, max_length=200)
    description: str = ""


class RunEntry(Strict):
    """One ``[[runs]]`` entry; keys beyond these are kept as the run's metadata (``Run.extra``)."""

    model_config = pydantic.ConfigDict(extra="allow")
    id: Id
    hours_post_mortem: float | None = Field(default=None, ge=0.0, le=10000.0)
    notes: str = ""


class DatasetFile(Strict):
    """The whole ``dataset.toml``."""

    dataset: DatasetInfo
    line: Line
    kpi: KpiSettings
    runs: list[RunEntry] = Field(min_length=1)


@dataclass
class Run:
    """One run: its ``[[runs]]`` entry and its four tables (contract column order, extra columns after)."""

    id: str
    hours_post_mortem: float | None
    notes: str
    fish: pd.DataFrame
    tracks: pd.DataFrame = field(default_factory=lambda: empty_table(TRACKS))
    photoeyes: pd.DataFrame = field(default_factory=lambda: empty_table(PHOTOEYES))
    belts: pd.DataFrame = field(default_factory=lambda: empty_table(BELTS))
    extra: dict[str, Any] = field(default_factory=dict)
    """Keys of the ``[[runs]]`` entry beyond id, hours_post_mortem and notes."""
    filled: dict[str, list[str]] = field(default_factory=dict)
    """fish.csv column -> ids of the fish whose empty value was filled in (regression or run value)."""
    path: Path | None = None
    """The run's folder when it was read from disk."""


@dataclass
class Dataset:
    """A dataset: the line it was measured on, the KPI settings and its runs."""

    name: str
    description: str
    line: Line
    kpi: KpiSettings
    runs: list[Run]
    path: Path | None = None

    def run(self, run_id: str) -> Run:
        for r in self.runs:
            if r.id == run_id:
                return r
        raise KeyError(run_id)


# ---------------------------------------------------------------------------------------- reading
def _row(index: Any) -> int:
    """Line number in the file of a data row (header is line 1, blank lines counted)."""
    return int(index) + 2


def read_table(path: Path, spec: TableSpec) -> pd.DataFrame:
    """Read one CSV: required columns present, numbers parsed, required values present and finite.

    The returned frame keeps the file's line numbers in its index (``index + 2``).
    """
    text = _read_text(path)
    _check_field_counts(text, path)
    try:
        # index_col=False: a row with more fields than the header never turns the first column into an index
        df = pd.read_csv(io.StringIO(text), dtype={c: str for c in spec.text}, skip_blank_lines=False,
                         index_col=False)
    except pd.errors.EmptyDataError:
        raise InputError(f"file is empty; expected a header line: {','.join(spec.columns)}", file=path) from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"not a readable CSV file: {str(exc).strip()}", file=path) from None
    df.columns = [str(c).strip() for c in df.columns]
    df = df.dropna(how="all")  # blank lines
    required = [c for c in spec.columns if c not in spec.may_be_empty]
    missing = [c for c in required if c not in df.columns]
    if missing:
        raise InputError(f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                         f"(found: {', '.join(df.columns)}; expected: {', '.join(spec.columns)})",
                         file=path, where="line 1 (header)")
    for c in spec.may_be_empty:
        if c not in df.columns:
            df[c] = np.nan
    for c in spec.columns:
        if c in spec.text:
            df[c] = df[c].str.strip()
            _fail_first(df[c].isna() | (df[c] == ""), path, c, "empty, a value is required")
            continue
        if not pd.api.types.is_numeric_dtype(df[c]):
            num = pd.to_numeric(df[c], errors="coerce")
            text = num.isna() & df[c].notna()
            if text.any():
                _fail_first(text, path, c, f"not a number: {df[c][text].iloc[0]!r}")
            df[c] = num
        df[c] = df[c].astype(float)
        if c not in spec.may_be_empty:
            _fail_first(df[c].isna(), path, c, "empty or NaN, a value is required")
        inf = np.isinf(df[c])
        if inf.any():
            _fail_first(inf, path, c, f"not a finite number ({df[c][inf].iloc[0]})")
    return df[list(spec.columns) + [c for c in df.columns if c not in spec.columns]]


def _read_text(path: Path) -> str:
    """The file as text: UTF-8 (a byte-order mark is dropped).  Anything else names the line and column
    of the first byte that is not UTF-8 (a Latin-1 or Windows-1252 export, typically)."""
    if path.is_file():
        file_size_checked(path, MAX_CSV_BYTES, "dataset CSV file")  # before reading it into memory
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", file=path) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a CSV file", file=path) from None
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror or exc}", file=path) from None
    data = data.removeprefix(b"\xef\xbb\xbf")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        start = data.rfind(b"\n", 0, exc.start) + 1
        field = data.count(b",", start, exc.start)
        header = data.split(b"\n", 1)[0].decode("utf-8", errors="replace").strip().split(",")
        column = f", column {header[field].strip()}" if line > 1 and field < len(header) else ""
        where = "line 1 (header)" if line == 1 else f"row {line}{column}"
        raise InputError(f"not UTF-8 text: byte 0x{data[exc.start]:02x} cannot be decoded (a file saved as Latin-1 "
                         "or Windows-1252?); save it as UTF-8", file=path, where=where) from None


def _check_field_counts(text: str, path: Path) -> None:
    """Every row has at most as many fields as the header, and every header field has a name: a trailing
    comma (an extra, empty field) would otherwise shift or add columns."""
    def too_many(line: int, record: list[str], n: int) -> InputError:
        hint = "; a trailing comma adds an empty field" if all(not f.strip() for f in record[n:]) else ""
        return InputError(f"{len(record)} fields, but the header has {n}{hint}", file=path, where=f"row {line}")

    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader, None)
        if header is None:
            return
        unnamed = [i for i, name in enumerate(header) if not name.strip()]
        if unnamed and len(header) > 1:
            trailing = " (a trailing comma?)" if unnamed == [len(header) - 1] else ""
            raise InputError(f"field {unnamed[0] + 1} of the header has no column name{trailing}", file=path,
                             where="line 1 (header)")
        if '"' not in text:  # no quoting: count the commas of every line at once (a drive log has 10^4-10^5 rows)
            chars = np.frombuffer(text.encode("utf-8"), np.uint8)
            commas_per_line = np.bincount(np.searchsorted(np.flatnonzero(chars == 10), np.flatnonzero(chars == 44)),
                                          minlength=1)
            bad = np.flatnonzero(commas_per_line[1:] >= len(header))
            if len(bad):
                line = int(bad[0]) + 2
                raise too_many(line, text.split("\n", line)[line - 1].rstrip("\r").split(","), len(header))
            return
        end = reader.line_num
        for record in reader:
            line, end = end + 1, reader.line_num
            if len(record) > len(header):
                raise too_many(line, record, len(header))
    except csv.Error as exc:
        raise InputError(f"not a readable CSV file: {exc}", file=path, where=f"row {reader.line_num}") from None


def _fail_first(mask: pd.Series, path: Path, column: str, message: str) -> None:
    """Raise, naming the first row where ``mask`` is True (if any)."""
    if mask.any():
        i = int(np.argmax(mask.to_numpy()))
        raise InputError(message, file=path, where=f"row {_row(mask.index[i])}, column {column}")


def _check_ids(df: pd.DataFrame, column: str, allowed: list[str], path: Path, what: str) -> None:
    bad = ~df[column].isin(allowed)
    if bad.any():
        value = df[column][bad].iloc[0]
        known = ", ".join(allowed[:12]) + (f", ... ({len(allowed)} in all)" if len(allowed) > 12 else "")
        _fail_first(bad, path, column, f"unknown {column} '{value}': not {what} (known: {known or 'none'})")


def _check_increasing(df: pd.DataFrame, key: str, path: Path) -> None:
    """Within each ``key`` (a fish, a conveyor) ``t_s`` must increase from row to row."""
    codes = pd.factorize(df[key])[0]
    order = np.argsort(codes, kind="stable")
    t = df["t_s"].to_numpy(float)[order]
    bad = np.flatnonzero((codes[order][1:] == codes[order][:-1]) & (t[1:] <= t[:-1]))
    if len(bad):
        k = bad[np.argmin(order[bad + 1])]  # the first offending row in file order
        row, prev = df.index[order[k + 1]], df.index[order[k]]
        raise InputError(f"{key} '{df[key].iloc[order[k]]}': t_s = {t[k + 1]:g} is not after its previous sample "
                         f"(t_s = {t[k]:g} in row {_row(prev)}); time must increase within each {key}",
                         file=path, where=f"row {_row(row)}, column t_s")


def _first(mask: pd.Series) -> Any | None:
    """Index label of the first row where ``mask`` is True, or None."""
    m = mask.to_numpy(dtype=bool)
    return mask.index[int(np.argmax(m))] if m.any() else None


def _refuse(path: Path, label: Any, column: str, message: str) -> None:
    raise InputError(message, file=path, where=f"row {_row(label)}, column {column}")


def _check_fish(fish: pd.DataFrame, path: Path, line: Line) -> None:
    """Sizes a salmon can have, drops within the line and above a belt."""
    length = fish["length_m"]
    lo, hi = LENGTH_RANGE_M
    i = _first((length < lo) | (length > hi))
    if i is not None:
        _refuse(path, i, "length_m", f"length_m = {length[i]:g} m is not a plausible salmon length "
                                     f"(allowed {lo:g} to {hi:g} m)")
    expected = pd.Series(np.asarray(length_regressions().weight_kg(length.to_numpy(float)), dtype=float),
                         index=fish.index)
    ratio = fish["weight_kg"] / expected
    i = _first((ratio > WEIGHT_FACTOR) | (ratio < 1.0 / WEIGHT_FACTOR))
    if i is not None:
        e = expected[i]
        _refuse(path, i, "weight_kg", f"weight_kg = {fish['weight_kg'][i]:g} kg is not plausible for a "
                                      f"{length[i]:g} m salmon: the length-weight regression gives {e:.3g} kg, and "
                                      f"{e / WEIGHT_FACTOR:.3g} to {e * WEIGHT_FACTOR:.3g} kg (a factor "
                                      f"{WEIGHT_FACTOR:g} either way) is allowed")
    for c, (a, b) in (("height_m", HEIGHT_PER_LENGTH), ("width_m", WIDTH_PER_LENGTH)):
        v = fish[c]
        i = _first(v.notna() & ((v < a * length) | (v > b * length)))
        if i is not None:
            _refuse(path, i, c, f"{c} = {v[i]:g} m is not plausible for a {length[i]:g} m salmon (allowed "
                                f"{a * length[i]:.3g} to {b * length[i]:.3g} m: {a:g} to {b:g} times its length)")
    h = fish["hours_post_mortem"]
    i = _first(h.notna() & ((h < 0) | (h > MAX_HOURS_POST_MORTEM)))
    if i is not None:
        _refuse(path, i, "hours_post_mortem", f"hours_post_mortem = {h[i]:g} must be between 0 (just slaughtered) "
                                              f"and {MAX_HOURS_POST_MORTEM:g}")
    x = fish["drop_x_m"]
    i = _first((x < line.x_start_m) | (x > line.x_end_m))
    if i is not None:
        _refuse(path, i, "drop_x_m", f"drop_x_m = {x[i]:g} m is outside the line: its conveyors span "
                                     f"x = {line.x_start_m:g} to {line.x_end_m:g} m")
    y, half = fish["drop_y_m"], 0.5 * line.guide_width_m
    i = _first(y.abs() > half)
    if i is not None:
        _refuse(path, i, "drop_y_m", f"drop_y_m = {y[i]:g} m is outside the side guides (y = +-{half:g} m)")
    z = fish["drop_z_m"]
    i = _first((z < 0) | (z > MAX_DROP_HEIGHT_M))
    if i is not None:
        where = "below the belt top" if z[i] < 0 else "too high"
        _refuse(path, i, "drop_z_m", f"drop_z_m = {z[i]:g} m is {where}: the height of the fish's lowest point "
                                     f"above the belt at release must be between 0 (lying on it) and "
                                     f"{MAX_DROP_HEIGHT_M:g} m")


def _check_footprint(fish: pd.DataFrame, path: Path, line: Line) -> None:
    """A dropped fish fits between the guides (with heights filled in from the regressions)."""
    yaw = fish["drop_yaw_rad"]
    reach = (fish["drop_y_m"].abs() + 0.5 * fish["length_m"] * np.abs(np.sin(yaw))
             + 0.5 * fish["height_m"] * np.abs(np.cos(yaw)))
    half = 0.5 * line.guide_width_m
    i = _first(reach > half + GUIDE_OVERLAP_M)
    if i is not None:
        _refuse(path, i, "drop_y_m", f"a {fish['length_m'][i]:g} m fish at drop_y_m = {fish['drop_y_m'][i]:g} m "
                                     f"with drop_yaw_rad = {yaw[i]:g} would reach {reach[i] - half:.3f} m into a "
                                     f"side guide (at y = +-{half:g} m; at most {GUIDE_OVERLAP_M:g} m is allowed): "
                                     "it cannot lie there")


def _check_belts(belts: pd.DataFrame, path: Path, line: Line) -> None:
    """Every conveyor logged, speeds a belt can run at."""
    logged = set(belts["conveyor_id"].unique())
    missing = [c.id for c in line.conveyors if c.id not in logged]
    if missing:
        raise InputError(f"no rows for conveyor{'s' if len(missing) > 1 else ''} {', '.join(missing)}: every "
                         "conveyor of the line must be in the drive log (an unlogged belt cannot be re-simulated)",
                         file=path, where="column conveyor_id")
    for c in ("setpoint_mps", "speed_mps"):
        i = _first(belts[c].abs() > MAX_BELT_SPEED_MPS)
        if i is not None:
            _refuse(path, i, c, f"{c} = {belts[c][i]:g} m/s is not a belt speed (|speed| at most "
                                f"{MAX_BELT_SPEED_MPS:g} m/s)")


def _check_times(run_id: str, *tables: tuple[pd.DataFrame, Path]) -> None:
    """Times from the run's start, within the drive log, and a re-simulation of bounded length.

    ``tables``: (fish, tracks, photoeyes, belts), each with its file."""
    (fish, fish_file), (tracks, tracks_file), (pe, pe_file), (belts, belts_file) = tables
    log_end = float(belts["t_s"].max())
    checks = [(fish, fish_file, "drop_t_s", log_end), (tracks, tracks_file, "t_s", log_end + CLOCK_SLACK_S),
              (pe, pe_file, "t_on_s", log_end + CLOCK_SLACK_S), (pe, pe_file, "t_off_s", log_end + CLOCK_SLACK_S),
              (belts, belts_file, "t_s", np.inf)]
    for df, path, c, limit in checks:
        t = df[c]
        i = _first(t < 0)
        if i is not None:
            _refuse(path, i, c, f"{c} = {t[i]:g} s is before the run's start (times are seconds from it, >= 0)")
        i = _first(t > limit)
        if i is not None:
            slack, why = (("", "belt speeds are known only while they were logged") if c == "drop_t_s" else
                          (f" by more than {CLOCK_SLACK_S:g} s", "what a run records must lie within its drive log"))
            _refuse(path, i, c, f"{c} = {t[i]:g} s is after the end of the drive log{slack} (belts.csv ends at "
                                f"t_s = {log_end:g} s): {why}")
    # what a re-simulation covers (fishfmu.analysis.resim.run_duration_s): the last drop, track sample or interval end
    for df, path, c in ((fish, fish_file, "drop_t_s"), (tracks, tracks_file, "t_s"), (pe, pe_file, "t_off_s")):
        i = _first(df[c] + 1.0 > MAX_RESIM_S)
        if i is not None:
            _refuse(path, i, c, f"{c} = {df[c][i]:g} s: re-simulating run '{run_id}' would simulate more than "
                                f"{MAX_RESIM_S:g} s, the limit per re-simulation (a measured batch takes about a "
                                "minute); split the run")


def read_run(dataset_path: str | Path, run_entry: RunEntry | Mapping[str, Any], line: Line,
             check_physics: bool = True) -> Run:
    """Read and check ``runs/<id>/`` of the dataset at ``dataset_path`` (a folder).

    ``check_physics``: also check that the run is physically plausible and can be re-simulated (fish
    sizes, drops within the line and above a belt, belt speeds, times within the drive log and
    :data:`MAX_RESIM_S`, every conveyor logged); off only for a run this program simulated itself
    (a replay of a run that stopped early has fish that were never dropped)."""
    entry = run_entry if isinstance(run_entry, RunEntry) else validate(RunEntry, dict(run_entry), prefix="runs")
    folder = Path(dataset_path) / "runs" / entry.id
    if not folder.is_dir():
        raise InputError(f"run '{entry.id}' is listed in dataset.toml but its folder is missing", file=folder)
    fish_file, tracks_file, pe_file, belts_file = (folder / s.file for s in TABLES)
    fish = read_table(fish_file, FISH)
    if fish.empty:
        raise InputError("no fish: a run needs at least one fish row", file=fish_file)
    dup = fish["fish_id"].duplicated()
    if dup.any():
        _fail_first(dup, fish_file, "fish_id", f"fish_id '{fish['fish_id'][dup].iloc[0]}' appears twice")
    for c in POSITIVE:
        bad = fish[c] <= 0
        if bad.any():
            _fail_first(bad, fish_file, c, f"must be > 0 (got {fish[c][bad].iloc[0]:g})")
    if check_physics:
        _check_fish(fish, fish_file, line)
    tracks = read_table(tracks_file, TRACKS)
    _check_ids(tracks, "fish_id", list(fish["fish_id"]), tracks_file, "a fish of fish.csv")
    _check_increasing(tracks, "fish_id", tracks_file)
    pe = read_table(pe_file, PHOTOEYES)
    _check_ids(pe, "sensor_id", [p.id for p in line.photoeyes], pe_file, "a photo-eye of the line")
    bad = pe["t_off_s"] < pe["t_on_s"]
    _fail_first(bad, pe_file, "t_off_s", "t_off_s is before t_on_s: an interval must end after it starts")
    belts = read_table(belts_file, BELTS)
    _check_ids(belts, "conveyor_id", [c.id for c in line.conveyors], belts_file, "a conveyor of the line")
    _check_increasing(belts, "conveyor_id", belts_file)
    if check_physics:
        _check_belts(belts, belts_file, line)
        _check_times(entry.id, (fish, fish_file), (tracks, tracks_file), (pe, pe_file), (belts, belts_file))

    filled: dict[str, list[str]] = {}
    reg = length_regressions()
    for c, values in (("height_m", reg.height_m(fish["length_m"])), ("width_m", reg.width_m(fish["length_m"])),
                      ("hours_post_mortem", np.full(len(fish), np.nan if entry.hours_post_mortem is None
                                                    else entry.hours_post_mortem))):
        empty = fish[c].isna()
        if c == "hours_post_mortem":
            _fail_first(empty & np.isnan(values), fish_file, c,
                        "empty, and the run has no hours_post_mortem in dataset.toml to fall back on")
        if empty.any():
            fish.loc[empty, c] = np.asarray(values)[empty.to_numpy()]
            filled[c] = list(fish["fish_id"][empty])
    if check_physics:
        _check_footprint(fish, fish_file, line)
    tables = [df.reset_index(drop=True) for df in (fish, tracks, pe, belts)]
    return Run(entry.id, entry.hours_post_mortem, entry.notes, *tables, extra=dict(entry.model_extra or {}),
               filled=filled, path=folder)


def _check_run_entries(doc: DatasetFile, toml: Path) -> None:
    seen: dict[str, int] = {}
    known = list(RunEntry.model_fields)
    for i, entry in enumerate(doc.runs):
        if entry.id in seen:
            raise InputError(f"run '{entry.id}' is listed twice (also runs[{seen[entry.id]}])", file=toml,
                             where=f"runs[{i}].id")
        seen[entry.id] = i
        for key in entry.model_extra or {}:
            hint = suggest(key, known, cutoff=0.8)
            if hint:
                raise InputError(f"unknown key '{key}'{hint}", file=toml, where=f"runs[{i}].{key}")


def read_dataset(path: str | Path, check_physics: bool = True) -> Dataset:
    """Read a dataset folder (or its ``dataset.toml``) and all its runs (``check_physics``: see :func:`read_run`)."""
    path = Path(path)
    toml = path / "dataset.toml" if path.is_dir() else path
    doc = validate(DatasetFile, read_toml(toml), file=toml)
    try:
        doc.kpi.check_against(doc.line)
    except ValueError as exc:
        raise InputError(str(exc), file=toml, where="kpi") from None
    _check_run_entries(doc, toml)
    runs = [read_run(toml.parent, entry, doc.line, check_physics) for entry in doc.runs]
    return Dataset(doc.dataset.name, doc.dataset.description, doc.line, doc.kpi, runs, toml.parent)


# ---------------------------------------------------------------------------------------- writing
def _ordered(df: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    missing = [c for c in spec.columns if c not in df.columns and c not in spec.may_be_empty]
    if missing:
        raise ValueError(f"{spec.file}: table lacks column(s) {', '.join(missing)}")
    df = df.assign(**{c: np.nan for c in spec.may_be_empty if c not in df.columns})
    return df[list(spec.columns) + [c for c in df.columns if c not in spec.columns]]


def write_run(run: Run, folder: str | Path) -> None:
    """Write the run's four CSVs into ``folder`` (created if needed); floats round-trip exactly."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fish = run.fish.copy()
    for c, ids in run.filled.items():
        fish.loc[fish["fish_id"].isin(ids), c] = np.nan  # written empty, as measured
    for spec, df in zip(TABLES, (fish, run.tracks, run.photoeyes, run.belts)):
        _ordered(df, spec).to_csv(folder / spec.file, index=False, na_rep="")


def run_entry(run: Run) -> dict[str, Any]:
    """The run's ``[[runs]]`` entry as a TOML-ready dict."""
    entry: dict[str, Any] = {"id": run.id}
    if run.hours_post_mortem is not None:
        entry["hours_post_mortem"] = float(run.hours_post_mortem)
    entry["notes"] = run.notes
    return entry | run.extra


def write_dataset(dataset: Dataset, path: str | Path) -> None:
    """Write ``dataset.toml`` and every run under ``runs/`` into the folder ``path``."""
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    doc = {"dataset": {"name": dataset.name, "description": dataset.description},
           "line": dataset.line.model_dump(mode="json"),
           "kpi": dataset.kpi.model_dump(mode="json", exclude_none=True),
           "runs": [run_entry(r) for r in dataset.runs]}
    with (root / "dataset.toml").open("wb") as fh:
        tomli_w.dump(doc, fh)
    for r in dataset.runs:
        write_run(r, root / "runs" / r.id)
