"""Reading and writing the measured-data format (contracts/measured-data.md)."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.errors import InputError
from plant.fish.fish_data import length_regressions
from plant.contract.kpis import compute_kpis
from plant.contract.measured import Run, read_dataset, write_dataset, write_run

PILOT_A = Path(__file__).parents[2] / "shared" / "data" / "pilot_a"


SMALL_DATASET_TOML = """\
[dataset]
name = "small"
description = "two runs on a two-belt line, made by hand for the reader tests"

[line]
guide_width_m = 0.5

[[line.conveyors]]
id = "c1"
x_start_m = 0.0
length_m = 2.0
width_m = 0.5
z_top_m = 0.0

[[line.conveyors]]
id = "c2"
x_start_m = 2.0
length_m = 2.0
width_m = 0.5
z_top_m = -0.02

[[line.photoeyes]]
id = "pe_in"
x_m = 1.0
z_m = 0.015

[[line.photoeyes]]
id = "pe_out"
x_m = 3.8
z_m = -0.005

[kpi]
infeed_photoeye = "pe_in"
outfeed_photoeye = "pe_out"
min_gap_m = 0.05

[[runs]]
id = "r1"
hours_post_mortem = 6.0
notes = "three fish"

[[runs]]
id = "r2"
hours_post_mortem = 30.0
notes = "two fish"
operator = "kari"
"""


def _small_run(folder: Path, fish_rows: list[str], fish_header: str, n_fish: int, hours: float) -> None:
    folder.mkdir(parents=True)
    (folder / "fish.csv").write_text(fish_header + "\n" + "\n".join(fish_rows) + "\n")
    tracks = ["t_s,fish_id,x_m,y_m,yaw_rad"]
    for k in range(n_fish):
        for i in range(8):
            t = 1.0 + k * 2.0 + 0.04 * i
            tracks.append(f"{t:.2f},f{k + 1:02d},{0.5 + 0.5 * 0.04 * i:.4f},0.0,0.0")
    tracks.sort(key=lambda r: (r[0] != "t", float(r.split(",")[0]) if r[0] != "t" else 0.0))
    (folder / "tracks.csv").write_text("\n".join(tracks) + "\n")
    (folder / "photoeyes.csv").write_text("sensor_id,t_on_s,t_off_s\npe_in,1.2,2.4\npe_in,3.2,4.4\n"
                                          "pe_out,8.0,9.0\npe_out,10.0,11.0\n")
    belts = ["t_s,conveyor_id,setpoint_mps,speed_mps"]
    for i in range(25):  # the drive log covers the run (0-12 s): drops, tracks and photo-eyes are within it
        for c, v in (("c1", 0.5), ("c2", 1.0)):
            belts.append(f"{0.5 * i:.2f},{c},{v},{v}")
    (folder / "belts.csv").write_text("\n".join(belts) + "\n")


@pytest.fixture
def small_dataset(tmp_path: Path) -> Path:
    """A tiny valid dataset (two runs, extras and empty cells included) that tests may mutate."""
    root = tmp_path / "small"
    root.mkdir()
    (root / "dataset.toml").write_text(SMALL_DATASET_TOML)
    header = "fish_id,length_m,weight_kg,height_m,width_m,hours_post_mortem,drop_t_s,drop_x_m,drop_y_m,drop_yaw_rad,drop_z_m"
    _small_run(root / "runs" / "r1", [
        "f01,0.6,2.0,0.14,0.065,6.0,0.5,0.5,0.0,0.0,0.05",
        "f02,0.5,1.2,0.11,0.05,6.0,2.5,0.5,0.1,0.1,0.05",
        "f03,0.62,2.2,0.15,0.07,6.0,4.5,0.5,-0.1,3.1,0.05"], header, 3, 6.0)
    _small_run(root / "runs" / "r2", [
        "f01,0.6,2.0,0.14,0.065,30.0,0.5,0.5,0.0,0.0,0.05,A",
        "f02,0.58,1.8,,0.06,30.0,2.5,0.5,0.1,0.1,0.05,B"], header + ",quality", 2, 30.0)
    return root


# --------------------------------------------------------------------------------------- valid data
def test_small_dataset_reads_with_contract_columns_and_extras(small_dataset: Path) -> None:
    ds = read_dataset(small_dataset)
    assert [r.id for r in ds.runs] == ["r1", "r2"]
    assert ds.kpi.outfeed_photoeye == "pe_out" and ds.line.conveyor_at(3.5).id == "c2"
    r1, r2 = ds.runs
    assert list(r1.fish.columns[:3]) == ["fish_id", "length_m", "weight_kg"]
    assert list(r1.tracks.columns) == ["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]
    assert r2.extra == {"operator": "kari"} and r2.hours_post_mortem == 30.0
    assert list(r2.fish["quality"]) == ["A", "B"]  # unknown extra column kept
    # f02 of r2 has no height: filled from the length regression, and said so
    assert r2.filled == {"height_m": ["f02"]}
    assert r2.fish["height_m"].iloc[1] == pytest.approx(float(length_regressions().height_m(0.58)))
    assert r1.filled == {}


def test_empty_hours_take_the_run_value(small_dataset: Path) -> None:
    fish_csv = small_dataset / "runs" / "r1" / "fish.csv"
    fish = pd.read_csv(fish_csv)
    fish.loc[2, "hours_post_mortem"] = np.nan
    fish.to_csv(fish_csv, index=False)
    r1 = read_dataset(small_dataset).run("r1")
    assert r1.fish["hours_post_mortem"].tolist() == [6.0, 6.0, 6.0]
    assert r1.filled == {"hours_post_mortem": ["f03"]}


def test_write_then_read_gives_the_same_run(small_dataset: Path, tmp_path: Path) -> None:
    ds = read_dataset(small_dataset)
    r1 = ds.run("r1")
    r1.tracks.loc[5, "x_m"] = 0.1 + 0.2  # 0.30000000000000004 must survive
    write_dataset(ds, tmp_path / "copy")
    back = read_dataset(tmp_path / "copy")
    assert back.line == ds.line and back.kpi == ds.kpi and back.name == ds.name
    for a, b in zip(ds.runs, back.runs):
        assert (a.id, a.hours_post_mortem, a.notes, a.extra, a.filled) == (b.id, b.hours_post_mortem, b.notes,
                                                                          b.extra, b.filled)
        for name in ("fish", "tracks", "photoeyes", "belts"):
            pd.testing.assert_frame_equal(getattr(a, name), getattr(b, name))
    assert back.run("r1").tracks.loc[5, "x_m"] == 0.1 + 0.2
    # the filled height is written empty again, as it was measured
    assert pd.read_csv(tmp_path / "copy" / "runs" / "r2" / "fish.csv")["height_m"].isna().tolist() == [False, True]
    # writing what was read gives the same bytes
    write_dataset(back, tmp_path / "copy2")
    for f in (tmp_path / "copy").rglob("*.*"):
        assert f.read_bytes() == (tmp_path / "copy2" / f.relative_to(tmp_path / "copy")).read_bytes(), f


def test_write_run_accepts_a_simulated_run_without_optional_columns(tmp_path: Path) -> None:
    fish = pd.DataFrame({"fish_id": ["a"], "length_m": [0.6], "weight_kg": [2.5], "drop_t_s": [0.0],
                         "drop_x_m": [0.5], "drop_y_m": [0.0], "drop_yaw_rad": [0.0], "drop_z_m": [0.05]})
    write_run(Run("sim", 24.0, "", fish), tmp_path / "sim")
    header = (tmp_path / "sim" / "fish.csv").read_text().splitlines()[0]
    assert header == ("fish_id,length_m,weight_kg,height_m,width_m,hours_post_mortem,drop_t_s,drop_x_m,"
                      "drop_y_m,drop_yaw_rad,drop_z_m")
    assert (tmp_path / "sim" / "tracks.csv").read_text().strip() == "t_s,fish_id,x_m,y_m,yaw_rad"


@pytest.fixture(scope="module")
def pilot_a():
    if not PILOT_A.is_dir():
        pytest.skip("pilot_a dataset not present")
    return read_dataset(PILOT_A)


def test_pilot_a_reads_12_runs_of_18_fish(pilot_a) -> None:
    assert len(pilot_a.runs) == 12
    assert all(len(r.fish) == 18 for r in pilot_a.runs)
    assert pilot_a.kpi.outfeed_photoeye == "pe_c4"
    assert all(set(r.photoeyes["sensor_id"]) <= {"pe_c1", "pe_c2", "pe_c3", "pe_c4"} for r in pilot_a.runs)


def test_pilot_a_kpis_compute_for_every_run(pilot_a) -> None:
    for r in pilot_a.runs:
        k = compute_kpis(r, pilot_a.line, pilot_a.kpi)
        assert k["fish_in"] == 18 and 0 <= k["singulated"] <= 18 and k["lost"] >= 0
        assert k["throughput_time_s"] > 0 and k["method"] in ("tracks", "mixed", "photoeyes")
        assert set(k["arrival_t_s"]) == {"pe_c1", "pe_c2", "pe_c3", "pe_c4"}
        json.dumps(k, allow_nan=False)


# --------------------------------------------------------------------------------------- bad data
def _csv(root: Path, run: str, name: str) -> Path:
    return root / "runs" / run / f"{name}.csv"


def _edit_csv(root: Path, run: str, name: str, edit) -> None:
    path = _csv(root, run, name)
    df = pd.read_csv(path, dtype={"fish_id": str, "sensor_id": str, "conveyor_id": str})
    edit(df)
    df.to_csv(path, index=False)


def _edit_toml(root: Path, old: str, new: str) -> None:
    path = root / "dataset.toml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def _set(name: str, row: int, column: str, value) -> callable:
    def edit(df: pd.DataFrame) -> None:
        if isinstance(value, str) and df[column].dtype != object:
            df[column] = df[column].astype(object)
        df.loc[row, column] = value
    return edit


def _set_many(row: int, **values: float) -> callable:
    def edit(df: pd.DataFrame) -> None:
        for column, value in values.items():
            df.loc[row, column] = value
    return edit


def _append_belt_rows(t_s: float) -> callable:
    def edit(df: pd.DataFrame) -> None:
        for c, v in (("c1", 0.5), ("c2", 1.0)):
            df.loc[len(df)] = [t_s, c, v, v]
    return edit


def _edit_bytes(root: Path, run: str, name: str, edit) -> None:
    path = _csv(root, run, name)
    path.write_bytes(edit(path.read_bytes()))


def _trailing_comma(lines) -> callable:
    """A comma at the end of these lines (1: the header)."""
    def edit(data: bytes) -> bytes:
        rows = data.split(b"\n")
        return b"\n".join(r + b"," if i + 1 in lines and r else r for i, r in enumerate(rows))
    return edit


# (mutation of the small dataset, things str(InputError) must name)
BAD_INPUTS = {
    "missing column": (lambda r: _edit_csv(r, "r1", "tracks", lambda df: df.pop("x_m")),
                       ["r1/tracks.csv", "line 1", "missing required column x_m"]),
    "NaN in tracks": (lambda r: _edit_csv(r, "r1", "tracks", _set("tracks", 7, "x_m", np.nan)),
                      ["r1/tracks.csv", "row 9, column x_m", "empty or NaN"]),
    "NaN in belts": (lambda r: _edit_csv(r, "r2", "belts", _set("belts", 0, "speed_mps", np.nan)),
                     ["r2/belts.csv", "row 2, column speed_mps"]),
    "text in a number column": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 1, "length_m", "long")),
                                ["r1/fish.csv", "row 3, column length_m", "not a number: 'long'"]),
    "negative length": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 2, "length_m", -0.6)),
                        ["r1/fish.csv", "row 4, column length_m", "must be > 0"]),
    "duplicate fish": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 2, "fish_id", "f01")),
                       ["r1/fish.csv", "row 4, column fish_id", "'f01' appears twice"]),
    "empty fish.csv": (lambda r: _csv(r, "r1", "fish").write_text(_csv(r, "r1", "fish").read_text().splitlines()[0]),
                       ["r1/fish.csv", "no fish"]),
    "zero-byte file": (lambda r: _csv(r, "r1", "photoeyes").write_text(""), ["r1/photoeyes.csv", "file is empty"]),
    "broken CSV": (lambda r: _csv(r, "r1", "belts").write_text('t_s,conveyor_id,setpoint_mps,speed_mps\n0,"c1,1,1\n'),
                   ["r1/belts.csv", "not a readable CSV"]),
    "missing CSV": (lambda r: _csv(r, "r2", "belts").unlink(), ["r2/belts.csv", "file not found"]),
    "unknown fish id": (lambda r: _edit_csv(r, "r1", "tracks", _set("tracks", 10, "fish_id", "f99")),
                        ["r1/tracks.csv", "row 12, column fish_id", "unknown fish_id 'f99'"]),
    "unknown sensor": (lambda r: _edit_csv(r, "r1", "photoeyes", _set("photoeyes", 3, "sensor_id", "pe_mid")),
                       ["r1/photoeyes.csv", "row 5, column sensor_id", "'pe_mid'", "pe_in, pe_out"]),
    "unknown conveyor": (lambda r: _edit_csv(r, "r1", "belts", _set("belts", 4, "conveyor_id", "c9")),
                         ["r1/belts.csv", "row 6, column conveyor_id", "'c9'"]),
    "t_off before t_on": (lambda r: _edit_csv(r, "r1", "photoeyes", _set("photoeyes", 1, "t_off_s", 0.0)),
                          ["r1/photoeyes.csv", "row 3, column t_off_s", "before t_on_s"]),
    "missing run folder": (lambda r: shutil.rmtree(r / "runs" / "r2"), ["runs/r2", "run 'r2'", "folder is missing"]),
    "run listed twice": (lambda r: _edit_toml(r, 'id = "r2"', 'id = "r1"'),
                         ["dataset.toml", "runs[1].id", "'r1' is listed twice"]),
    "unknown key with suggestion": (lambda r: _edit_toml(r, "min_gap_m = 0.05", "min_gap = 0.05"),
                                    ["dataset.toml", "kpi.min_gap", "did you mean 'min_gap_m'"]),
    "misspelt run key": (lambda r: _edit_toml(r, "hours_post_mortem = 30.0", "hours_postmortem = 30.0"),
                         ["dataset.toml", "runs[1].hours_postmortem", "did you mean 'hours_post_mortem'"]),
    "unknown table": (lambda r: _edit_toml(r, "[kpi]", "[kpis]"), ["dataset.toml", "kpis", "did you mean 'kpi'"]),
    "bad line geometry": (lambda r: _edit_toml(r, "x_start_m = 2.0", "x_start_m = 1.5"),
                          ["dataset.toml", "line", "overlap"]),
    "outfeed photo-eye not on the line": (lambda r: _edit_toml(r, 'outfeed_photoeye = "pe_out"',
                                                                'outfeed_photoeye = "pe_end"'),
                                          ["dataset.toml", "kpi", "'pe_end' is not a photo-eye"]),
    "TOML syntax": (lambda r: _edit_toml(r, "[kpi]", "[kpi"), ["dataset.toml", "TOML syntax error"]),
    # physically implausible: refused before anything is simulated (plant.contract.measured's bounds)
    "drop outside the guides": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 1, "drop_y_m", 0.4)),
                                ["r1/fish.csv", "row 3, column drop_y_m", "outside the side guides"]),
    "drop beyond the line": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 0, "drop_x_m", 7.5)),
                             ["r1/fish.csv", "row 2, column drop_x_m", "outside the line", "x = 0 to 4 m"]),
    "drop below the belt": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 2, "drop_z_m", -0.1)),
                            ["r1/fish.csv", "row 4, column drop_z_m", "below the belt top"]),
    "drop from 1000 m": (lambda r: _edit_csv(r, "r2", "fish", _set("fish", 1, "drop_z_m", 1000.0)),
                         ["r2/fish.csv", "row 3, column drop_z_m", "too high", "2 m"]),
    "fish across the channel": (lambda r: _edit_csv(r, "r1", "fish", _set_many(0, drop_y_m=0.1, drop_yaw_rad=1.5708)),
                                ["r1/fish.csv", "row 2, column drop_y_m", "into a side guide"]),
    "5 m fish": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 1, "length_m", 5.0)),
                 ["r1/fish.csv", "row 3, column length_m", "not a plausible salmon length", "0.2 to 1.5 m"]),
    "weight in grams": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 0, "weight_kg", 2000.0)),
                        ["r1/fish.csv", "row 2, column weight_kg", "not plausible for a 0.6 m salmon"]),
    "height in centimetres": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 0, "height_m", 14.0)),
                              ["r1/fish.csv", "row 2, column height_m", "not plausible"]),
    "negative hours post mortem": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 2, "hours_post_mortem", -2.0)),
                                   ["r1/fish.csv", "row 4, column hours_post_mortem", "between 0"]),
    "belts at 1e6 m/s": (lambda r: _edit_csv(r, "r1", "belts", _set("belts", 2, "speed_mps", 1e6)),
                         ["r1/belts.csv", "row 4, column speed_mps", "not a belt speed", "10 m/s"]),
    "drop after the drive log": (lambda r: _edit_csv(r, "r1", "fish", _set("fish", 0, "drop_t_s", 1e6)),
                                 ["r1/fish.csv", "row 2, column drop_t_s", "after the end of the drive log"]),
    "track before the start": (lambda r: _edit_csv(r, "r1", "tracks", _set("tracks", 0, "t_s", -1.0)),
                               ["r1/tracks.csv", "row 2, column t_s", "before the run's start"]),
    "photo-eye after the drive log": (lambda r: _edit_csv(r, "r2", "photoeyes", _set("photoeyes", 3, "t_off_s", 100.0)),
                                      ["r2/photoeyes.csv", "row 5, column t_off_s", "after the end of the drive log"]),
    "conveyor not logged": (lambda r: _edit_bytes(r, "r1", "belts",
                                                  lambda b: b"\n".join(x for x in b.split(b"\n") if b",c2," not in x)),
                            ["r1/belts.csv", "column conveyor_id", "no rows for conveyor c2"]),
    "run longer than a re-simulation may be": (lambda r: (_edit_csv(r, "r1", "belts", _append_belt_rows(700.0)),
                                                          _edit_csv(r, "r1", "fish", _set("fish", 2, "drop_t_s", 650.0))),
                                               ["r1/fish.csv", "row 4, column drop_t_s", "more than 600 s"]),
    # CSV text a reader must not misread
    "Latin-1 CSV": (lambda r: _edit_bytes(r, "r1", "fish", lambda b: b.replace(b"f02,", "f\u00f82,".encode("latin-1"))),
                    ["r1/fish.csv", "row 3, column fish_id", "not UTF-8"]),
    "trailing comma on a row": (lambda r: _edit_bytes(r, "r1", "tracks", _trailing_comma(lines=[5])),
                                ["r1/tracks.csv", "row 5:", "6 fields, but the header has 5", "trailing comma"]),
    "trailing comma on every row": (lambda r: _edit_bytes(r, "r2", "belts", _trailing_comma(lines=range(2, 100))),
                                    ["r2/belts.csv", "row 2:", "trailing comma"]),
    "trailing comma in the header too": (lambda r: _edit_bytes(r, "r1", "fish", _trailing_comma(lines=range(1, 5))),
                                         ["r1/fish.csv", "line 1 (header)", "no column name", "trailing comma"]),
}

# the line's own logs: a camera's detections.csv, a pusher's rejections.csv (issue 39, item 10)
WITH_LOGS = ("[kpi]", '[[line.cameras]]\nid = "cam"\nx_start_m = 0.5\nx_end_m = 3.5\n\n[[line.devices]]\nid = "push"\n'
                      'kind = "pusher"\nx_m = 2.5\nlength_m = 0.6\n\n[kpi]')
REJECTIONS_HEADER = "t_s,device_id,fish_id\n"
DETECTIONS_HEADER = "t_s,camera_id,track,x_back_m,x_front_m,y_m,length_m,heading,double\n"


def _with_log(name: str, text: str) -> callable:
    def mutate(root: Path) -> None:
        _edit_toml(root, *WITH_LOGS)
        _csv(root, "r1", name).write_text(text)
    return mutate


def _duplicated_column(name: str, column: str) -> callable:
    """``name``.csv of r1 with ``column`` repeated at the end of every line (pandas would read it as ``column.1``)."""
    def mutate(root: Path) -> None:
        df = pd.read_csv(_csv(root, "r1", name), dtype=str, keep_default_na=False)
        lines = [",".join([*df.columns, column])] + [",".join([*row, row[df.columns.get_loc(column)]])
                                                      for row in df.itertuples(index=False)]
        _csv(root, "r1", name).write_text("\n".join(lines) + "\n")
    return mutate


BAD_INPUTS.update({
    "rejections without a fish_id column": (_with_log("rejections", "t_s,device_id\n3.0,push\n"),
                                            ["r1/rejections.csv", "line 1 (header)", "missing required column fish_id"]),
    "a fish rejected twice": (_with_log("rejections", REJECTIONS_HEADER + "3.0,push,f01\n4.0,push,f02\n5.0,push,f01\n"),
                              ["r1/rejections.csv", "row 4, column fish_id", "'f01' is rejected twice", "row 2"]),
    "more rejections than fish": (_with_log("rejections", REJECTIONS_HEADER + "".join(f"{t}.0,push,\n" for t in range(4))),
                                  ["r1/rejections.csv", "row 5", "4 rejections but the run has 3 fish"]),
    "heading 2": (_with_log("detections", DETECTIONS_HEADER + "1.0,cam,1,0.5,1.1,0.0,0.6,1,0\n1.1,cam,1,0.6,1.2,0.0,0.6,2,0\n"),
                  ["r1/detections.csv", "row 3, column heading", "heading = 2", "-1 (tail first), 0 (not known) or 1"]),
    "double 5": (_with_log("detections", DETECTIONS_HEADER + "1.0,cam,1,0.5,1.1,0.0,0.6,1,5\n"),
                 ["r1/detections.csv", "row 2, column double", "double = 5", "0 or 1"]),
    "track 1.5": (_with_log("detections", DETECTIONS_HEADER + "1.0,cam,1.5,0.5,1.1,0.0,0.6,1,0\n"),
                  ["r1/detections.csv", "row 2, column track", "track = 1.5", "a whole number from 1"]),
    "back ahead of the front": (_with_log("detections", DETECTIONS_HEADER + "1.0,cam,1,1.2,1.1,0.0,0.6,1,0\n"),
                                ["r1/detections.csv", "row 2, column x_back_m", "x_back_m = 1.2", "at most x_front_m"]),
    "duplicate column in tracks": (_duplicated_column("tracks", "x_m"),
                                   ["r1/tracks.csv", "line 1 (header), column x_m", "'x_m' appears twice"]),
    "duplicate column in fish": (_duplicated_column("fish", "length_m"),
                                 ["r1/fish.csv", "line 1 (header), column length_m", "appears twice"]),
    "duplicate column in detections": (_with_log("detections", DETECTIONS_HEADER.replace("\n", ",y_m\n")
                                                 + "1.0,cam,1,0.5,1.1,0.0,0.6,1,0,0.3\n"),
                                       ["r1/detections.csv", "column y_m", "appears twice"]),
    "duplicate column in rejections": (_with_log("rejections", "t_s,device_id,fish_id,device_id\n3.0,push,f01,push\n"),
                                       ["r1/rejections.csv", "column device_id", "appears twice"]),
})


def test_a_rejection_of_an_unknown_fish_is_read_as_such(small_dataset: Path) -> None:
    """docs/measured-data.md: ``fish_id`` may be empty where the log does not know the fish; two such rows may be
    the same fish or two, and the KPIs leave good_rejected undefined."""
    _with_log("rejections", REJECTIONS_HEADER + "3.0,push,\n4.0,push,f02\n5.0,push, \n")(small_dataset)
    ds = read_dataset(small_dataset)
    rej = ds.run("r1").rejections
    assert rej["fish_id"].isna().tolist() == [True, False, True] and rej["fish_id"][1] == "f02"
    k = compute_kpis(ds.run("r1"), ds.line, ds.kpi)
    assert k["rejected"] == 3 and k["good_rejected"] is None and k["rejected_by"] == {"push": 3}


@pytest.mark.timeout(60)  # the old reader waited on a FIFO for ever
@pytest.mark.parametrize("name", ["dataset.toml", "runs/r1/tracks.csv", "runs/r1/fish.csv", "runs/r1/rejections.csv"])
def test_a_fifo_in_a_dataset_is_refused_without_opening_it_for_reading(small_dataset: Path, name: str) -> None:
    _edit_toml(small_dataset, *WITH_LOGS)
    path = small_dataset / name
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    with pytest.raises(InputError, match="a FIFO") as info:
        read_dataset(small_dataset)
    assert Path(info.value.file) == path


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_names_file_and_place(small_dataset: Path, case: str) -> None:
    mutate, expected = BAD_INPUTS[case]
    mutate(small_dataset)
    with pytest.raises(InputError) as info:
        read_dataset(small_dataset)
    message = str(info.value).replace("\\", "/")
    for part in expected:
        assert part in message, f"{case}: {part!r} not in {message!r}"


def test_non_monotonic_track_time_names_row_and_fish(small_dataset: Path) -> None:
    path = _csv(small_dataset, "r1", "tracks")
    df = pd.read_csv(path)
    rows = df.index[df["fish_id"] == "f02"]
    i, j = rows[3], rows[4]  # f02's 4th and 5th samples swap times
    df.loc[[i, j], "t_s"] = df.loc[[j, i], "t_s"].to_numpy()
    df.to_csv(path, index=False)
    with pytest.raises(InputError) as info:
        read_dataset(small_dataset)
    message = str(info.value)
    assert "tracks.csv" in message and f"row {j + 2}, column t_s" in message
    assert "fish_id 'f02'" in message and f"row {i + 2}" in message


def test_row_numbers_count_blank_lines_as_a_person_does(small_dataset: Path) -> None:
    path = _csv(small_dataset, "r1", "fish")
    lines = path.read_text().splitlines()
    lines.insert(1, "")                      # line 2 is blank
    lines[3] = lines[3].replace(",0.5,", ",,", 1)  # line 4 (fish f02) loses its length
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=re.escape("row 4, column length_m")):
        read_dataset(small_dataset)


def test_empty_hours_without_a_run_value_is_an_error(small_dataset: Path) -> None:
    _edit_toml(small_dataset, "hours_post_mortem = 6.0\n", "")
    _edit_csv(small_dataset, "r1", "fish", _set("fish", 0, "hours_post_mortem", np.nan))
    with pytest.raises(InputError, match=r"fish\.csv: row 2, column hours_post_mortem: empty, and the run"):
        read_dataset(small_dataset)
