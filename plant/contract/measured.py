"""Reading and writing measured data (contracts/measured-data.md): real runs and simulated ones alike.

A dataset is a folder with ``dataset.toml`` (``[dataset]``, ``[line]``, ``[kpi]``, ``[[runs]]``) and one folder per
run under ``runs/`` with ``fish.csv``, ``tracks.csv``, ``photoeyes.csv`` and ``belts.csv``, and where the line has
them its cameras' ``detections.csv`` and its devices' ``rejections.csv``.  Readers check everything the contract
asks and stop at the first problem with an :class:`~plant.errors.InputError` naming the file and the key, or the row
(as a person counts lines in the file: the header is line 1) and column.  Nothing is dropped silently: extra CSV
columns are kept, extra keys of a ``[[runs]]`` entry are kept in ``Run.extra`` (unless they look like a misspelt
known key), and empty ``height_m``, ``width_m``, ``hours_post_mortem`` in fish.csv are filled (length regressions,
the run's value) and listed in ``Run.filled``; :func:`write_run` writes those cells empty again, so a round trip
gives back the same files. Blank lines in a CSV are skipped; pandas' usual NaN spellings (empty, NaN, NA, null) are
missing values. A CSV must be UTF-8 (a byte-order mark is allowed) and no row may have more fields than the header
(a trailing comma): the error names the row.

A run must also be physically plausible before anything is simulated: :func:`read_run` calls the
checks of :mod:`plant.contract.plausibility`, where the bounds and their reasons are.

Over 450 lines: one format's tables, their reading with every check, and their writing (which must give back
what was read); the plausibility checks are already apart.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pydantic
import tomli_w
from pydantic import Field

from plant.contract import plausibility
from plant.contract.device_commands import check_device_commands
from plant.errors import InputError
from plant.fish.fish_data import length_regressions
from plant.fish.population import FishSpec
from plant.contract.line import Id, KpiSettings, Line
from plant.contract.log_values import check_detections, check_rejections
from plant.contract.parts import part_triangles
from plant.contract.plausibility import MAX_HOURS_POST_MORTEM
from plant.contract.row_errors import fail_first, row_number
from plant.validation import MAX_CSV_BYTES, Strict, read_regular_file, read_toml, suggest, validate


@dataclass(frozen=True)
class TableSpec:
    """One CSV of a run: its columns in contract order, which hold text, which may be empty."""

    name: str
    columns: tuple[str, ...]
    text: frozenset[str]
    may_be_empty: frozenset[str] = frozenset()
    may_be_absent: frozenset[str] = frozenset()
    """Columns a file may leave out (read as empty); every other column of ``columns`` is required in the header."""

    @property
    def file(self) -> str:
        return f"{self.name}.csv"


FISH = TableSpec("fish", ("fish_id", "length_m", "weight_kg", "height_m", "width_m", "hours_post_mortem",
                          "drop_t_s", "drop_x_m", "drop_y_m", "drop_yaw_rad", "drop_z_m"),
                 frozenset({"fish_id"}), may_be_empty=frozenset({"height_m", "width_m", "hours_post_mortem"}),
                 may_be_absent=frozenset({"height_m", "width_m", "hours_post_mortem"}))
TRACKS = TableSpec("tracks", ("t_s", "fish_id", "x_m", "y_m", "yaw_rad"), frozenset({"fish_id"}))
PHOTOEYES = TableSpec("photoeyes", ("sensor_id", "t_on_s", "t_off_s"), frozenset({"sensor_id"}))
BELTS = TableSpec("belts", ("t_s", "conveyor_id", "setpoint_mps", "speed_mps"), frozenset({"conveyor_id"}))
TABLES = (FISH, TRACKS, PHOTOEYES, BELTS)
DETECTIONS = TableSpec("detections", ("t_s", "camera_id", "track", "x_back_m", "x_front_m", "y_m", "length_m",
                                      "heading", "double"), frozenset({"camera_id"}))
"""Optional: what the line's cameras logged, one row per fish in view per frame (absent: no camera log)."""
REJECTIONS = TableSpec("rejections", ("t_s", "device_id", "fish_id"), frozenset({"device_id", "fish_id"}),
                       frozenset({"fish_id"}))
"""Optional: the line's devices' log, one row per fish a device took off the line (``fish_id`` empty where the log
does not know which fish; absent: no device took any)."""
DEVICE_COMMANDS = TableSpec("device_commands", ("t_s", "device_id", "command"), frozenset({"device_id"}))
"""Optional: the line's PLC's log of its device commands, a row per change (:mod:`plant.contract.device_commands`;
absent: the commands were not logged, and a re-simulation cannot fire the devices as the line did)."""
POSITIVE = ("length_m", "weight_kg", "height_m", "width_m")


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
    hours_post_mortem: float | None = Field(default=None, ge=0.0, le=MAX_HOURS_POST_MORTEM)
    notes: str = ""


class DatasetFile(Strict):
    """The whole ``dataset.toml``."""

    dataset: DatasetInfo
    line: Line
    kpi: KpiSettings
    runs: list[RunEntry] = Field(min_length=1)


@dataclass
class Run:
    """One run: its ``[[runs]]`` entry and its tables (contract column order, extra columns after)."""

    id: str
    hours_post_mortem: float | None
    notes: str
    fish: pd.DataFrame
    tracks: pd.DataFrame = field(default_factory=lambda: empty_table(TRACKS))
    photoeyes: pd.DataFrame = field(default_factory=lambda: empty_table(PHOTOEYES))
    belts: pd.DataFrame = field(default_factory=lambda: empty_table(BELTS))
    detections: pd.DataFrame = field(default_factory=lambda: empty_table(DETECTIONS))
    """The cameras' log (``detections.csv``; empty without one)."""
    rejections: pd.DataFrame = field(default_factory=lambda: empty_table(REJECTIONS))
    """The devices' log (``rejections.csv``; empty without one)."""
    device_commands: pd.DataFrame | None = None
    """The devices' command log (``device_commands.csv``); None without one: the commands were not logged."""
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

    def subset(self, runs: list[Run]) -> Dataset:
        """The same dataset (line, KPI settings, name) with only ``runs``."""
        return replace(self, runs=list(runs))

    def run(self, run_id: str) -> Run:
        for r in self.runs:
            if r.id == run_id:
                return r
        raise KeyError(run_id)


# ---------------------------------------------------------------------------------------- reading

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
    missing = [c for c in spec.columns if c not in df.columns and c not in spec.may_be_absent]
    if missing:
        raise InputError(f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                         f"(found: {', '.join(df.columns)}; expected: {', '.join(spec.columns)})",
                         file=path, where="line 1 (header)")
    for c in spec.may_be_absent:
        if c not in df.columns:
            df[c] = np.nan
    for c in spec.columns:
        if c in spec.text:
            df[c] = df[c].astype(object).str.strip().replace("", np.nan)
            if c not in spec.may_be_empty:
                fail_first(df[c].isna(), path, c, "empty, a value is required")
            continue
        if not pd.api.types.is_numeric_dtype(df[c]):
            num = pd.to_numeric(df[c], errors="coerce")
            text = num.isna() & df[c].notna()
            if text.any():
                fail_first(text, path, c, f"not a number: {df[c][text].iloc[0]!r}")
            df[c] = num
        df[c] = df[c].astype(float)
        if c not in spec.may_be_empty:
            fail_first(df[c].isna(), path, c, "empty or NaN, a value is required")
        inf = np.isinf(df[c])
        if inf.any():
            fail_first(inf, path, c, f"not a finite number ({df[c][inf].iloc[0]})")
    return df[list(spec.columns) + [c for c in df.columns if c not in spec.columns]]


def _read_text(path: Path) -> str:
    """The file as text: UTF-8 (a byte-order mark is dropped).  Anything else names the line and column
    of the first byte that is not UTF-8 (a Latin-1 or Windows-1252 export, typically)."""
    data = read_regular_file(path, MAX_CSV_BYTES, "dataset CSV file")
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
        names = [name.strip() for name in header]
        twice = next((n for i, n in enumerate(names) if n and n in names[:i]), None)
        if twice is not None:
            raise InputError(f"column '{twice}' appears twice in the header: which one holds the values is unclear",
                             file=path, where=f"line 1 (header), column {twice}")
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


def _check_ids(df: pd.DataFrame, column: str, allowed: list[str], path: Path, what: str) -> None:
    bad = ~df[column].isin(allowed)
    if bad.any():
        value = df[column][bad].iloc[0]
        known = ", ".join(allowed[:12]) + (f", ... ({len(allowed)} in all)" if len(allowed) > 12 else "")
        fail_first(bad, path, column, f"unknown {column} '{value}': not {what} (known: {known or 'none'})")


def _check_increasing(df: pd.DataFrame, key: str, path: Path, strictly: bool = True) -> None:
    """Within each ``key`` (a fish, a conveyor) ``t_s`` must increase from row to row (``strictly=False``: must not
    decrease, for a camera that logs several fish per frame)."""
    codes = pd.factorize(df[key])[0]
    order = np.argsort(codes, kind="stable")
    t = df["t_s"].to_numpy(float)[order]
    back = (t[1:] <= t[:-1]) if strictly else (t[1:] < t[:-1])
    bad = np.flatnonzero((codes[order][1:] == codes[order][:-1]) & back)
    if len(bad):
        k = bad[np.argmin(order[bad + 1])]  # the first offending row in file order
        row, prev = df.index[order[k + 1]], df.index[order[k]]
        raise InputError(f"{key} '{df[key].iloc[order[k]]}': t_s = {t[k + 1]:g} is "
                         f"{'not after' if strictly else 'before'} its previous sample (t_s = {t[k]:g} in row "
                         f"{row_number(prev)}); time must {'increase' if strictly else 'not go back'} within each {key}",
                         file=path, where=f"row {row_number(row)}, column t_s")



def read_run(dataset_path: str | Path, run_entry: RunEntry | Mapping[str, Any], line: Line,
             check_physics: bool = True) -> Run:
    """Read and check ``runs/<id>/`` of the dataset at ``dataset_path`` (a folder).

    ``check_physics``: also check that the run is physically plausible and can be re-simulated (fish
    sizes, drops within the line and above a belt, belt speeds, times within the drive log and
    :data:`~plant.contract.plausibility.MAX_RESIM_S`, every conveyor logged); off only for a run this program simulated itself
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
        fail_first(dup, fish_file, "fish_id", f"fish_id '{fish['fish_id'][dup].iloc[0]}' appears twice")
    for c in POSITIVE:
        bad = fish[c] <= 0
        if bad.any():
            fail_first(bad, fish_file, c, f"must be > 0 (got {fish[c][bad].iloc[0]:g})")
    if check_physics:
        plausibility.check_fish(fish, fish_file, line)
    tracks = read_table(tracks_file, TRACKS)
    _check_ids(tracks, "fish_id", list(fish["fish_id"]), tracks_file, "a fish of fish.csv")
    _check_increasing(tracks, "fish_id", tracks_file)
    pe = read_table(pe_file, PHOTOEYES)
    _check_ids(pe, "sensor_id", [p.id for p in line.photoeyes], pe_file, "a photo-eye of the line")
    bad = pe["t_off_s"] < pe["t_on_s"]
    fail_first(bad, pe_file, "t_off_s", "t_off_s is before t_on_s: an interval must end after it starts")
    belts = read_table(belts_file, BELTS)
    _check_ids(belts, "conveyor_id", [c.id for c in line.conveyors], belts_file, "a conveyor of the line")
    _check_increasing(belts, "conveyor_id", belts_file)
    if check_physics:
        plausibility.check_belts(belts, belts_file, line)
        plausibility.check_times(entry.id, (fish, fish_file), (tracks, tracks_file), (pe, pe_file), (belts, belts_file))

    filled: dict[str, list[str]] = {}
    reg = length_regressions()
    for c, values in (("height_m", reg.height_m(fish["length_m"])), ("width_m", reg.width_m(fish["length_m"])),
                      ("hours_post_mortem", np.full(len(fish), np.nan if entry.hours_post_mortem is None
                                                    else entry.hours_post_mortem))):
        empty = fish[c].isna()
        if c == "hours_post_mortem":
            fail_first(empty & np.isnan(values), fish_file, c,
                        "empty, and the run has no hours_post_mortem in dataset.toml to fall back on")
        if empty.any():
            fish.loc[empty, c] = np.asarray(values)[empty.to_numpy()]
            filled[c] = list(fish["fish_id"][empty])
    if check_physics:
        plausibility.check_footprint(fish, fish_file, line)
    detections = _read_log(folder, DETECTIONS, "camera_id", [c.id for c in line.cameras], "a camera of the line")
    rejections = _read_log(folder, REJECTIONS, "device_id", [d.id for d in line.devices], "a device of the line")
    known = rejections["fish_id"].notna()
    _check_ids(rejections[known], "fish_id", list(fish["fish_id"]), folder / REJECTIONS.file, "a fish of fish.csv")
    check_rejections(rejections, len(fish), folder / REJECTIONS.file)
    check_detections(detections, folder / DETECTIONS.file, {c.id: c.position_noise_m for c in line.cameras})
    commands = _read_device_commands(folder, line, belts)
    tables = [df.reset_index(drop=True) for df in (fish, tracks, pe, belts, detections, rejections)]
    return Run(entry.id, entry.hours_post_mortem, entry.notes, *tables,
               device_commands=None if commands is None else commands.reset_index(drop=True),
               extra=dict(entry.model_extra or {}), filled=filled, path=folder)


def _read_device_commands(folder: Path, line: Line, belts: pd.DataFrame) -> pd.DataFrame | None:
    """The run's ``device_commands.csv``, checked (:func:`~plant.contract.device_commands.check_device_commands`);
    None without the file."""
    path = folder / DEVICE_COMMANDS.file
    if not path.exists():
        return None
    log = read_table(path, DEVICE_COMMANDS)
    check_device_commands(log, path, line, float(belts["t_s"].max()) if len(belts) else 0.0)
    return log


def _read_log(folder: Path, spec: TableSpec, column: str, allowed: list[str], what: str) -> pd.DataFrame:
    """An optional log of a run (cameras', devices'): its rows by time, each ``column`` one of ``allowed``; no rows
    without the file."""
    path = folder / spec.file
    if not path.exists():
        return empty_table(spec)
    log = read_table(path, spec)
    _check_ids(log, column, allowed, path, what)
    _check_increasing(log, column, path, strictly=False)
    return log


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
    doc.line = doc.line.with_parts_relative_to(toml.parent)
    part_triangles(doc.line)  # the parts' STL files as the re-simulation will read them
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
    """Write the run's four CSVs into ``folder`` (created if needed), and its cameras' and devices' logs when it has
    them; floats round-trip exactly."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fish = run.fish.copy()
    for c, ids in run.filled.items():
        fish.loc[fish["fish_id"].isin(ids), c] = np.nan  # written empty, as measured
    for spec, df in zip(TABLES, (fish, run.tracks, run.photoeyes, run.belts)):
        _ordered(df, spec).to_csv(folder / spec.file, index=False, na_rep="")
    for spec, df in ((DETECTIONS, run.detections), (REJECTIONS, run.rejections)):
        if len(df):
            _ordered(df, spec).to_csv(folder / spec.file, index=False, na_rep="")
    if run.device_commands is not None:  # a logged table, even of no rows (a line whose log is empty)
        _ordered(run.device_commands, DEVICE_COMMANDS).to_csv(folder / DEVICE_COMMANDS.file, index=False, na_rep="")


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
           "line": dataset.line.model_dump(mode="json", exclude_none=True,  # keys a line without them never had
                                           exclude={k for k in ("cameras", "parts", "devices")
                                                    if not getattr(dataset.line, k)}),
           "kpi": dataset.kpi.model_dump(mode="json", exclude_none=True),
           "runs": [run_entry(r) for r in dataset.runs]}
    with (root / "dataset.toml").open("wb") as fh:
        tomli_w.dump(doc, fh)
    for r in dataset.runs:
        write_run(r, root / "runs" / r.id)


# ---- fish.csv and the fish of a run ---------------------------------------------------------------------
def fish_to_frame(fish: list[FishSpec]) -> pd.DataFrame:
    """fish.csv as a table (contracts/measured-data.md column order)."""
    columns = list(FISH.columns)
    return pd.DataFrame([{c: getattr(f, c) for c in columns} for f in fish], columns=columns)


def fish_from_frame(df: pd.DataFrame, run_hours_post_mortem: float, rng: np.random.Generator) -> list[FishSpec]:
    """Fish from a measured fish.csv: the measured values where given, the regressions where empty.

    The side a fish lies on is not measured; it is drawn from ``rng``.
    """
    out = []
    reg = length_regressions()
    for row in df.itertuples(index=False):
        length = float(row.length_m)
        h = float(row.height_m) if pd.notna(getattr(row, "height_m", np.nan)) else float(reg.height_m(length))
        w = float(row.width_m) if pd.notna(getattr(row, "width_m", np.nan)) else float(reg.width_m(length))
        hpm = getattr(row, "hours_post_mortem", np.nan)
        out.append(FishSpec(
            fish_id=str(row.fish_id), length_m=length, height_m=h, width_m=w, weight_kg=float(row.weight_kg),
            hours_post_mortem=float(hpm) if pd.notna(hpm) else float(run_hours_post_mortem),
            drop_t_s=float(row.drop_t_s), drop_x_m=float(row.drop_x_m), drop_y_m=float(row.drop_y_m),
            drop_yaw_rad=float(row.drop_yaw_rad), drop_z_m=float(row.drop_z_m),
            side=1 if rng.random() < 0.5 else -1))
    return out
