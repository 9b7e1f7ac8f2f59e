"""Building the built-in FMUs: standalone archives that validate, rebuild from their own sources,
compile without warnings, keep C and XML in step, and a cache that two processes can fill at once."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu
from typer.testing import CliRunner

from fishfmu.fmu import build as fmu_build
from fishfmu.cli import app
from fishfmu.fmu.build import BUILTIN_FMUS, build_fmu, fmu_guid, source_digest
from tests.fmu_helpers import start_slave


@pytest.mark.parametrize("name", BUILTIN_FMUS)
def test_built_fmu_passes_fmpy_validation(builtin_fmus: dict[str, Path], name: str) -> None:
    assert validate_fmu(str(builtin_fmus[name])) == []


def test_build_fmu_writes_a_standalone_fmu_with_its_sources(tmp_path: Path) -> None:
    path = build_fmu("conveyor_drive", tmp_path / "out")
    assert path == tmp_path / "out" / "conveyor_drive.fmu"
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        sources = {n.removeprefix("sources/"): zf.read(n).decode() for n in names if n.startswith("sources/")}
    assert {"modelDescription.xml", "binaries/linux64/conveyor_drive.so"} <= names
    listed = [f.split("/")[-1] for f in read_model_description(str(path)).buildConfigurations[0]
              .sourceFileSets[0].sourceFiles]
    assert set(listed) == {n for n in sources if n.endswith(".c")}
    # every quoted include of every source is shipped too (so the sources build on their own)
    for text in sources.values():
        for header in re.findall(r'^\s*#include "([^"]+)"', text, re.MULTILINE):
            assert header in sources, header
    assert "documentation/licenses/fmi2-headers.txt" in names
    assert not list((tmp_path / "out").glob(".*"))  # no partial files left


def test_fmu_rebuilds_from_its_own_sources(builtin_fmus: dict[str, Path], tmp_path: Path) -> None:
    from fmpy import extract
    from fmpy.build import build_platform_binary
    unzipped = Path(extract(str(builtin_fmus["singulation_controller"]), str(tmp_path / "fmu")))
    shutil.rmtree(unzipped / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(unzipped, tmp_path / "build")  # as `fmpy compile` does, from sources/ only
    assert (unzipped / "binaries/linux64/singulation_controller.so").is_file()
    slave = start_slave(unzipped, {"n_belts": 2})
    assert slave.value("setpoint_2") == slave.value("speed_2") > 0.0  # last belt runs from the start
    slave.close()


@pytest.mark.parametrize("name", BUILTIN_FMUS)
def test_sources_compile_without_warnings(unzipped_fmus: dict[str, Path], tmp_path: Path, name: str) -> None:
    if shutil.which("gcc") is None:
        pytest.skip("gcc not available")
    sources = sorted(str(p) for p in (unzipped_fmus[name] / "sources").glob("*.c"))
    done = subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-O2", "-fPIC", "-shared",
                           "-I", str(unzipped_fmus[name] / "sources"), *sources, "-o", str(tmp_path / "x.so")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("name", BUILTIN_FMUS)
def test_c_value_references_match_the_model_description(unzipped_fmus: dict[str, Path], name: str) -> None:
    header = (unzipped_fmus[name] / "sources" / "model_variables.h").read_text()
    in_c = {m[0].lower(): int(m[1]) for m in re.findall(r"#define VR_(\w+) (\d+)", header)}
    table = (unzipped_fmus[name] / "sources" / "model_variables.c").read_text()
    names_in_table = re.findall(r'^\s+\{"(\w+)"', table, re.MULTILINE)
    md = read_model_description(str(unzipped_fmus[name]))
    in_xml = {v.name: v.valueReference for v in md.modelVariables}
    assert in_c == in_xml
    assert names_in_table == [v.name for v in sorted(md.modelVariables, key=lambda v: v.valueReference)]
    assert f'#define MODEL_GUID "{md.guid}"' in header


def test_guid_is_stable_and_follows_the_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    guid = fmu_guid("conveyor_drive", source_digest("conveyor_drive"))
    assert guid == fmu_guid("conveyor_drive", source_digest("conveyor_drive"))
    assert guid != fmu_guid("singulation_controller", source_digest("singulation_controller"))
    copy = tmp_path / "fmus"
    shutil.copytree(fmu_build.FMUS_DIR, copy)
    monkeypatch.setattr(fmu_build, "FMUS_DIR", copy)
    monkeypatch.setattr(fmu_build, "COMMON_DIR", copy / "common")
    assert fmu_guid("conveyor_drive", source_digest("conveyor_drive")) == guid  # same sources elsewhere
    with open(copy / "conveyor_drive" / "model.c", "a") as f:
        f.write("/* changed */\n")
    assert fmu_guid("conveyor_drive", source_digest("conveyor_drive")) != guid


def test_cache_is_filled_once_by_two_processes_at_once(tmp_path: Path) -> None:
    env = {**os.environ, "FISHFMU_CACHE": str(tmp_path / "cache")}
    code = "from fishfmu.fmu.build import builtin_fmu; print(builtin_fmu('singulation_controller'))"
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, cwd=Path(__file__).parents[1]) for _ in range(2)]
    results = [proc.communicate(timeout=300) for proc in procs]
    assert all(proc.returncode == 0 for proc in procs), [err for _, err in results]
    paths = {out.strip() for out, _ in results}
    assert len(paths) == 1
    fmu = Path(paths.pop())
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [fmu.parent.name]  # no staging folders left
    assert fmu.parent.name == source_digest("singulation_controller")
    assert validate_fmu(str(fmu)) == []


def test_cli_build_fmus_prints_the_paths(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["build-fmus", "--out", str(tmp_path), "singulation_controller"])
    assert result.exit_code == 0, result.output
    assert result.output.strip() == str(tmp_path / "singulation_controller.fmu")
    assert (tmp_path / "singulation_controller.fmu").is_file()


def test_unknown_fmu_name_is_an_input_error(tmp_path: Path) -> None:
    from plant.errors import InputError
    with pytest.raises(InputError, match="unknown built-in FMU 'conveyor'"):
        build_fmu("conveyor", tmp_path)
