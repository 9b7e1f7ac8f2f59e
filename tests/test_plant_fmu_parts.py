"""The exported plant FMU carries the line's STL parts (issue 39, item 9): inside ``resources/parts/``, named relative
to ``resources/scenario.toml``, so that the FMU moved elsewhere runs with its parts after the original file is gone,
and no file in it names a path of the exporting machine.  Bad parts are refused by export (tests/test_parts.py)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from stl import mesh

pytest.importorskip("pythonfmu")

from fishfmu.cosim.build import scenario_fish  # noqa: E402
from fishfmu.scenario.schema import load_scenario  # noqa: E402
from plant.sim.plant import Plant  # noqa: E402

ROOT = Path(__file__).parents[1]
SHELF_Z_M = 0.05


def with_a_shelf(folder: Path) -> Path:
    """paper_dump with a 2 x 0.5 m shelf (in millimetres) 5 cm over the whole infeed belt: dropped fish land on it."""
    m = mesh.Mesh(np.zeros(2, dtype=mesh.Mesh.dtype))
    m.vectors = np.array([[[0, -250, 0], [2000, -250, 0], [2000, 250, 0]],
                          [[0, -250, 0], [2000, 250, 0], [0, 250, 0]]], float)
    m.save(str(folder / "shelf.stl"))
    text = (ROOT / "scenarios" / "paper_dump.toml").read_text()
    at = text.index("[[line.conveyors]]")
    part = f'[[line.parts]]\nid = "shelf"\nstl = "shelf.stl"\nscale = 0.001\noffset_m = [0.0, 0.0, {SHELF_Z_M}]\n\n'
    (folder / "shelf.toml").write_text(text[:at] + part + text[at:])
    return folder / "shelf.toml"


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path]:
    """(the exported FMU, the scenario it was exported from)."""
    src = tmp_path_factory.mktemp("exporter")
    scenario = with_a_shelf(src)
    out = src / "shelf.fmu"
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "export-fmu", str(scenario), "--out", str(out)],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    return out, scenario


def test_the_fmu_names_its_parts_relative_to_its_scenario_and_no_machine_path(exported):
    fmu, scenario = exported
    with zipfile.ZipFile(fmu) as z:
        members = {n: z.read(n) for n in z.namelist()}
    inside = tomllib.loads(members["resources/scenario.toml"].decode())
    assert inside["line"]["parts"][0]["stl"] == "parts/0_shelf.stl"
    assert members["resources/parts/0_shelf.stl"] == (scenario.parent / "shelf.stl").read_bytes()
    machine_paths = {str(scenario.parent), str(scenario.parent.resolve()), str(ROOT), str(Path.home()), sys.prefix}
    for name, data in members.items():
        for path in machine_paths:
            assert path.encode() not in data, f"{name} names {path}"


def test_moved_and_without_the_original_stl_the_fmu_runs_with_its_part(exported, tmp_path):
    from fmpy import simulate_fmu
    fmu, scenario = exported
    moved = tmp_path / "elsewhere" / "shelf.fmu"
    moved.parent.mkdir()
    moved.write_bytes(fmu.read_bytes())
    (scenario.parent / "shelf.stl").rename(scenario.parent / "shelf.stl.gone")
    try:
        res = simulate_fmu(str(moved), stop_time=6.0, step_size=0.01, output_interval=0.01,
                           start_values={"fish_count": 1, "seed": 1}, output=["c1.load_mass", "fish_dropped"])
    finally:
        (scenario.parent / "shelf.stl.gone").rename(scenario.parent / "shelf.stl")
    assert len(res) == 601 and res["fish_dropped"][-1] == 1  # every step done: the plant was built with its part
    # the fish dropped at 4 s lies on the shelf, not on the belt: the belt carries nothing; without the shelf
    # fishfmu's own plant has the fish's mass on the belt
    sc = load_scenario(scenario, {"fish.count": 1, "run.seed": 1})
    bare = sc.line.model_copy(update={"parts": []})
    plant = Plant(bare, scenario_fish(sc), sc.plant, sc.run.comm_step_s)
    for _ in range(600):
        out = plant.step({c: 0.0 for c in plant.conveyor_ids})
    assert out.belt_load_mass_kg["c1"] == pytest.approx(scenario_fish(sc)[0].weight_kg, rel=0.05)
    assert np.all(res["c1.load_mass"][-100:] == 0.0)
