"""Fixed parts from STL files (``[[line.parts]]``): static contact surfaces fish land and rest on; a file that
cannot be read, or a part placed where contact is not searched, is refused naming the part; relative paths are
the scenario's."""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from stl import mesh

from plant.contract.line import Line
from plant.contract.parts import MAX_PART_TRIANGLES, part_triangles
from plant.errors import InputError
from plant.sim.plant import Plant
from tests.chromium import CHROMIUM, Browser
from tests.plant_helpers import fish
from tests.test_bad_input import assert_one_clear_line, run_main, sandbox  # noqa: F401 (a fixture, used by name)

from fishfmu import commands
from fishfmu.scenario.schema import load_scenario

needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM}: `apt-get install chromium`")

PLATE_Z_M = 0.10


def plate(path: Path) -> Path:
    """A 0.8 x 0.3 m plate in millimetres, its normal up."""
    m = mesh.Mesh(np.zeros(2, dtype=mesh.Mesh.dtype))
    m.vectors = np.array([[[0, 0, 0], [800, 0, 0], [800, 300, 0]], [[0, 0, 0], [800, 300, 0], [0, 300, 0]]], float)
    m.save(str(path))
    return path


def line_with(part: dict | None) -> Line:
    return Line.model_validate({"guide_width_m": 0.5, "parts": [part] if part else [], "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 3.0, "width_m": 0.5, "z_top_m": 0.0}]})


def resting_height(line: Line) -> float:
    """The mid-length point's height of a fish dropped from 20 cm at x = 1.4 m onto the stopped line, after 1 s."""
    plant = Plant(line, [fish("f1", 0.6, x_m=1.4, z_m=0.2)])
    for _ in range(100):
        plant.step({"c1": 0.0})
    return float(plant.state.fish_poses().z_m[0])


def test_a_fish_dropped_over_a_plate_rests_on_it_not_on_the_belt(tmp_path):
    on_belt = resting_height(line_with(None))
    on_plate = resting_height(line_with({"id": "plate", "stl": str(plate(tmp_path / "plate.stl")), "scale": 0.001,
                                         "offset_m": [1.0, -0.15, PLATE_Z_M]}))
    assert 0.0 < on_belt < 0.05  # half the fish's thickness above the belt
    assert on_plate - on_belt == pytest.approx(PLATE_Z_M, abs=0.01)


def test_an_unreadable_or_misplaced_part_is_refused_naming_it(tmp_path):
    with pytest.raises(InputError) as err:
        Plant(line_with({"id": "chute", "stl": str(tmp_path / "missing.stl")}), [])
    assert "line.parts[0].stl" in str(err.value) and "missing.stl" in str(err.value) and "chute" in str(err.value)
    with pytest.raises(InputError, match="outside the space over the line"):
        Plant(line_with({"id": "plate", "stl": str(plate(tmp_path / "plate.stl"))}), [])  # in mm, not scaled: 800 m


def scenario_with_a_plate(folder: Path) -> Path:
    """The dumped paper test with the plate 20 cm over its second belt, the STL named relative to the scenario."""
    plate(folder / "plate.stl")
    text = (Path(__file__).parents[1] / "scenarios" / "paper_dump.toml").read_text()
    at = text.index("[[line.conveyors]]")
    part = '[[line.parts]]\nid = "plate"\nstl = "plate.stl"\nscale = 0.001\noffset_m = [2.5, -0.15, 0.2]\n\n'
    (folder / "with_part.toml").write_text(text[:at] + part + text[at:])
    return folder / "with_part.toml"


def test_a_relative_stl_path_is_the_scenarios(tmp_path):
    sc = load_scenario(scenario_with_a_plate(tmp_path))
    assert sc.line.parts[0].stl == str((tmp_path / "plate.stl").resolve())


@needs_chromium
def test_the_replay_draws_a_part_where_it_is(tmp_path):
    done = commands.run(scenario_with_a_plate(tmp_path), tmp_path / "out",
                        {"fish.count": 2, "run.duration_s": 5.0, "expect": {}}, report=False, replay=True)
    assert done.result.status == "ok"
    browser = Browser()
    try:
        browser.open(done.replay.as_uri())
        browser.eval("window.replay.ready")
        browser.eval("window.replay.setView('top'); window.replay.setTime(0.5)")
        on_plate = browser.eval("window.replay.project([2.9, 0.0, 0.2])")[:2]
        beside = browser.eval("window.replay.project([2.9, 0.2, -0.02])")[:2]  # the belt next to it
        img = np.asarray(Image.open(io.BytesIO(browser.screenshot())).convert("RGB")).astype(int)
    finally:
        browser.close()
    bright = [img[int(round(y)), int(round(x))].mean() for x, y in (on_plate, beside)]
    assert bright[0] > bright[1] + 40, bright  # the light grey plate over the dark belt


# ---------------------------------------------------------------- bad STL files, found before anything is written

def binary_stl(triangles: np.ndarray, claimed: int | None = None) -> bytes:
    """A binary STL of ``triangles`` (n x 3 x 3) whose header claims ``claimed`` triangles (default: n)."""
    data = np.zeros(len(triangles), dtype=mesh.Mesh.dtype)
    data["vectors"] = triangles
    return b"\0" * 80 + np.uint32(len(triangles) if claimed is None else claimed).tobytes() + data.tobytes()


ONE_TRIANGLE = np.array([[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.2, 0.0]]])


def _fifo(path: Path) -> None:
    os.mkfifo(path)


BAD_STL: dict[str, tuple[Callable[[Path], object], tuple[str, ...]]] = {
    "missing": (lambda p: None, ("STL file not found",)),
    "garbage": (lambda p: p.write_bytes(bytes(range(256)) * 3), ("claims", "triangles but the file holds")),
    "garbage text": (lambda p: p.write_text("solid plate\n  this is not a facet\nendsolid\n"), ("cannot read as STL",)),
    "empty": (lambda p: p.write_bytes(b""), ("no triangles",)),
    "out of range": (lambda p: p.write_bytes(binary_stl(ONE_TRIANGLE * 1000)), ("outside the space over the line",)),
    "NaN vertex": (lambda p: p.write_bytes(binary_stl(np.where(np.arange(9).reshape(1, 3, 3) == 4, np.nan,
                                                               ONE_TRIANGLE))), ("non-finite vertex",)),
    "header claims 99 999 999 triangles": (lambda p: p.write_bytes(binary_stl(np.repeat(ONE_TRIANGLE, 2, axis=0),
                                                                              claimed=99_999_999)),
                                           ("claims 99999999 triangles", "holds 2")),
    "more triangles than the limit": (lambda p: p.write_bytes(binary_stl(np.repeat(ONE_TRIANGLE,
                                                                                   MAX_PART_TRIANGLES + 1, axis=0))),
                                      (f"has {MAX_PART_TRIANGLES + 1} triangles", f"at most {MAX_PART_TRIANGLES}")),
    "FIFO": (_fifo, ("a FIFO",)),
    "folder": (lambda p: p.mkdir(), ("a folder",)),
}


def scenario_naming(folder: Path, stl: str) -> Path:
    """paper_dump with one part whose ``stl`` is the given path (relative to the scenario)."""
    text = (Path(__file__).parents[1] / "scenarios" / "paper_dump.toml").read_text()
    at = text.index("[[line.conveyors]]")
    part = f'[[line.parts]]\nid = "chute"\nstl = "{stl}"\noffset_m = [1.0, -0.1, 0.2]\n\n'
    (folder / "with_part.toml").write_text(text[:at] + part + text[at:])
    return folder / "with_part.toml"


@pytest.mark.timeout(120)  # the old code waited on a FIFO for ever
@pytest.mark.parametrize("command", ["check", "run", "export-fmu"])
@pytest.mark.parametrize("case", list(BAD_STL))
def test_a_bad_stl_file_is_refused_by_every_command_before_it_writes(case, command, sandbox, capsys, monkeypatch):
    make, expected = BAD_STL[case]
    make(sandbox / "chute.stl")
    scenario = scenario_naming(sandbox, "chute.stl")
    args = {"check": [], "run": ["--out", "out"], "export-fmu": ["--out", "plant.fmu"]}[command]
    code, err = run_main(sandbox, capsys, monkeypatch, command, str(scenario), *args)
    assert_one_clear_line(code, err, "chute.stl", "line.parts[0].stl", *expected)


def test_a_device_file_as_stl_is_refused_not_read():
    line = line_with({"id": "chute", "stl": "/dev/zero"})
    with pytest.raises(InputError, match="a device or socket") as err:
        part_triangles(line)
    assert err.value.where == "line.parts[0].stl"


def test_the_triangle_limit_holds_for_all_parts_together(tmp_path):
    half = MAX_PART_TRIANGLES // 2 + 1
    (tmp_path / "a.stl").write_bytes(binary_stl(np.repeat(ONE_TRIANGLE + [1.0, 0.0, 0.0], half, axis=0)))
    parts = [{"id": f"p{i}", "stl": str(tmp_path / "a.stl")} for i in range(2)]
    line = Line.model_validate({"guide_width_m": 0.5, "parts": parts, "conveyors": [
        {"id": "c1", "x_start_m": 0.0, "length_m": 3.0, "width_m": 0.5, "z_top_m": 0.0}]})
    with pytest.raises(InputError, match=f"at most {MAX_PART_TRIANGLES} together") as err:
        part_triangles(line)
    assert err.value.where == "line.parts[1].stl"  # the first fits, the second goes over


def test_a_binary_stl_whose_header_begins_with_solid_is_read_as_binary(tmp_path):
    data = bytearray(binary_stl(ONE_TRIANGLE + [1.0, 0.0, 0.0]))
    data[:15] = b"solid SolidWork"  # as SolidWorks writes its binary files
    (tmp_path / "sw.stl").write_bytes(bytes(data))
    pts, trigs = part_triangles(line_with({"id": "sw", "stl": str(tmp_path / "sw.stl")}))
    assert np.allclose(pts, [[1.0, 0.0, 0.0], [1.3, 0.0, 0.0], [1.3, 0.2, 0.0]]) and trigs == [[0, 1, 2]]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_part_offset_that_is_not_finite_is_refused_naming_the_key(value, sandbox, capsys, monkeypatch):
    plate(sandbox / "plate.stl")
    scenario = scenario_with_a_plate(sandbox)
    scenario.write_text(scenario.read_text().replace("offset_m = [2.5, -0.15, 0.2]", f"offset_m = [2.5, {value}, 0.2]"))
    code, err = run_main(sandbox, capsys, monkeypatch, "check", str(scenario))
    line = assert_one_clear_line(code, err, "with_part.toml", "line.parts[0].offset_m[1]", "finite number")
    assert "plate.stl" not in line


def test_a_nul_in_a_parts_path_is_bad_input_not_a_bug(sandbox, capsys, monkeypatch):
    scenario = scenario_naming(sandbox, "sh\\u0000elf.stl")  # TOML's escape: a NUL in the path
    code, err = run_main(sandbox, capsys, monkeypatch, "check", str(scenario))
    assert_one_clear_line(code, err, "with_part.toml", "line.parts[0].stl", "not a usable path")
