"""A machine that lacks what pip cannot install: the shared libraries Exudyn's compiled module loads
(libGL.so.1, libX11.so.6) or the build tools the built-in FMUs are compiled with.  Each is one line
naming what is missing and the Debian/Ubuntu package that provides it, exit 3, never "internal error"
(exit 4), and nothing written."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from plant.errors import SystemDependencyError

from fishfmu.cli.exit_codes import EXIT_SIMULATION_FAILED

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_test.toml"
LOADER_MESSAGE = "libGL.so.1: cannot open shared object file: No such file or directory"
"""What the dynamic loader says when an extension module needs libGL.so.1 and the system has none."""


@pytest.fixture(scope="module")
def exudyn_without_libgl(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder to put first on PYTHONPATH: an ``exudyn`` package with Exudyn's own ``__init__.py``
    whose compiled modules fail to load as they do on a host without libGL.so.1, so the message is the
    one the installed Exudyn gives (its list of attempts), not a copy of it."""
    root = tmp_path_factory.mktemp("no_libgl")
    package = root / "exudyn"
    package.mkdir()
    shutil.copy(importlib.util.find_spec("exudyn").origin, package / "__init__.py")
    for module in ("exudynCPP", "exudynCPPfast"):
        (package / f"{module}.py").write_text(f"raise ImportError({LOADER_MESSAGE!r})\n")
    return root


def fishfmu(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, **env}, timeout=300)


def test_the_stand_in_fails_as_exudyn_does_without_libgl(exudyn_without_libgl: Path) -> None:
    done = subprocess.run([sys.executable, "-c", "import exudyn"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(exudyn_without_libgl)}, timeout=60)
    assert "ImportError: Exudyn could not import its compiled module" in done.stderr
    assert f".exudynCPP  ->  {LOADER_MESSAGE}" in done.stderr


@pytest.mark.parametrize("command", [["run", str(PAPER)], ["check", str(PAPER)]])
def test_missing_libgl_is_one_line_naming_the_library_and_its_package(exudyn_without_libgl: Path, tmp_path: Path,
                                                                       command: list[str]) -> None:
    out = tmp_path / "out"
    done = fishfmu(*command, *(["--out", str(out)] if command[0] == "run" else []),
                   env={"PYTHONPATH": str(exudyn_without_libgl)})
    assert done.returncode == EXIT_SIMULATION_FAILED, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("missing system package: this machine lacks libGL.so.1, which Exudyn")
    assert "apt-get install libgl1" in lines[0]
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr
    assert not out.exists()


def test_each_library_exudyn_loads_names_its_package_and_an_unknown_one_how_to_find_it() -> None:
    from plant.sim.exudyn_module import EXUDYN_LIBRARY_PACKAGES, exudyn_import_error
    assert EXUDYN_LIBRARY_PACKAGES["libX11.so.6"] == "libx11-6"
    both = exudyn_import_error(ImportError("Exudyn could not import its compiled module. Tried, in order:\n"
                                           "  .exudynCPP  ->  libX11.so.6: cannot open shared object file: No such "
                                           "file or directory\n  .exudynCPPfast  ->  libGL.so.1: cannot open shared "
                                           "object file: No such file or directory"))
    assert isinstance(both, SystemDependencyError)
    assert "lacks libX11.so.6 and libGL.so.1" in str(both) and "apt-get install libx11-6 libgl1" in str(both)
    unknown = exudyn_import_error(ImportError("libfoo.so.3: cannot open shared object file: No such file"))
    assert "lacks libfoo.so.3" in str(unknown) and "apt-file search libfoo.so.3" in str(unknown)
    # not a missing library (a wheel for another Python): not ours to explain, it stays as it was
    assert exudyn_import_error(ImportError("No module named 'exudynCPP'")) is None


def test_no_c_compiler_is_one_line_naming_build_essential_and_nothing_is_built(tmp_path: Path) -> None:
    empty_path = tmp_path / "bin"  # no cc, c++, make (nor cmake: the one pip installed would be used)
    empty_path.mkdir()
    cache = tmp_path / "fmu_cache"
    out = tmp_path / "out"
    done = fishfmu("run", str(PAPER), "--out", str(out), env={"PATH": str(empty_path), "FISHFMU_CACHE": str(cache)})
    assert done.returncode == EXIT_SIMULATION_FAILED, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("missing system package: cannot compile the FMU ")
    assert "no C compiler (cc, gcc or clang), C++ compiler (c++, g++ or clang++) or make found" in lines[0]
    assert "apt-get install build-essential" in lines[0]
    assert "internal error" not in done.stderr
    assert not out.exists() and not any(cache.rglob("*.fmu"))


def _tools(folder: Path, *names: str) -> Path:
    folder.mkdir()
    for name in names:
        (folder / name).write_text("#!/bin/sh\nexit 0\n")
        (folder / name).chmod(0o755)
    return folder


def test_a_c_compiler_alone_is_not_enough(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ubuntu's gcc package without g++: fmpy's CMake project asks for a C++ compiler too."""
    from fishfmu.fmu.compile import missing_build_tools, require_build_tools
    for variable in ("CC", "CXX", "CMAKE_GENERATOR"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setenv("PATH", str(_tools(tmp_path / "bin", "gcc", "make")))
    assert missing_build_tools() == ["C++ compiler (c++, g++ or clang++)"]
    monkeypatch.setenv("CXX", "clang++-17")
    with pytest.raises(SystemDependencyError, match=r"no C\+\+ compiler \(\$CXX is 'clang\+\+-17'\) found; .*"
                                                    r"apt-get install build-essential"):
        require_build_tools("conveyor_drive")


def test_cmake_comes_from_pip_when_the_venv_is_not_activated(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from fishfmu.fmu.compile import cmake_program
    monkeypatch.setenv("PATH", str(_tools(tmp_path / "bin", "cc")))
    cmake = Path(cmake_program())
    assert cmake.name == "cmake" and os.access(cmake, os.X_OK)
    assert subprocess.run([str(cmake), "--version"], capture_output=True, text=True).stdout.startswith("cmake version")


def test_a_compiler_that_fails_is_one_line_with_its_first_error(tmp_path: Path) -> None:
    """A compiler that cannot compile (here: one that always fails) ends the first run with one line
    from CMake's or the compiler's output, exit 3, not an internal error."""
    broken = tmp_path / "bin"
    broken.mkdir()
    for name in ("cc", "c++", "make"):
        (broken / name).write_text("#!/bin/sh\necho 'cc1: error: out of order on purpose' >&2\nexit 1\n")
        (broken / name).chmod(0o755)
    out = tmp_path / "out"
    done = fishfmu("run", str(PAPER), "--out", str(out), env={"PATH": str(broken), "FISHFMU_CACHE": str(tmp_path / "c")})
    assert done.returncode == EXIT_SIMULATION_FAILED, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("build failed: CMake configure of the FMU ")
    assert "is not able to compile a simple test program" in lines[0] and "internal error" not in lines[0]
    assert not out.exists()


def test_our_sources_failing_to_compile_name_the_file_line_and_error(tmp_path: Path) -> None:
    from fishfmu.fmu.build import FMUS_DIR, build_fmu
    from fishfmu.fmu.compile import FmuBuildError, missing_build_tools
    if missing_build_tools():
        pytest.skip("no C build tools on this machine")
    sources = tmp_path / "conveyor_drive"
    shutil.copytree(FMUS_DIR / "conveyor_drive", sources)
    lines = (sources / "model.c").read_text().splitlines()
    (sources / "model.c").write_text("\n".join([*lines, "int broken( {"]) + "\n")
    with pytest.raises(FmuBuildError) as caught:
        build_fmu("conveyor_drive", tmp_path / "out", model_dir=sources)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith("C build of the FMU 'conveyor_drive' failed (exit code ")
    assert f"fmu/sources/model.c:{len(lines) + 1}:" in message and "error:" in message
    assert "fishfmu-build-" not in message  # the temporary build folder is not what the user needs to see
