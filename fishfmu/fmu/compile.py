"""Compiling an FMU's C sources into its binary with fmpy's CMake project (as ``fmpy compile`` does): the build
tools a machine needs (checked before CMake runs, named with the package that brings them), and a failure told in
one line, the compiler's or CMake's first error.  What is compiled: :mod:`fishfmu.fmu.build`.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import fmpy
from fmpy.build import create_cmake_settings

from plant.errors import SystemDependencyError


class FmuBuildError(RuntimeError):
    """The C compiler or CMake failed on our sources; the message carries their first error line."""


BUILD_PACKAGE = "build-essential"
"""The Debian/Ubuntu package with what fmpy's CMake project needs besides CMake (pip installs that):
a C compiler, a C++ compiler (its ``project()`` enables C++ too), make and the C library's headers."""
BUILD_TOOLS = (("C compiler", "CC", ("cc", "gcc", "clang")),
               ("C++ compiler", "CXX", ("c++", "g++", "clang++")),  # fmpy's CMakeLists' project() enables C++
               ("make", None, ("gmake", "make")))
"""What CMake looks for (in $CC / $CXX when set, else these names on PATH, in its own order)."""


def missing_build_tools() -> list[str]:
    """The build tools this machine lacks, each as the message names it (empty when all are there).

    >>> import os; os.environ["CC"] = "no-such-cc"; missing_build_tools()[0]
    "C compiler ($CC is 'no-such-cc')"
    >>> del os.environ["CC"]
    """
    missing = []
    for what, variable, names in BUILD_TOOLS:
        if variable is None and os.environ.get("CMAKE_GENERATOR", "Unix Makefiles") != "Unix Makefiles":
            continue  # another generator brings its own build program: CMake reports it if it is missing
        chosen = os.environ.get(variable, "").split() if variable else []
        if chosen:
            if shutil.which(chosen[0]) is None:
                missing.append(f"{what} (${variable} is '{chosen[0]}')")
        elif not any(shutil.which(n) for n in names):
            missing.append(what if len(names) < 3 else f"{what} ({', '.join(names[:-1])} or {names[-1]})")
    return missing


def require_build_tools(name: str) -> None:
    """Raise SystemDependencyError naming what is missing to compile the built-in FMU ``name``."""
    missing = missing_build_tools()
    if missing:
        tools = missing[0] if len(missing) == 1 else f"{', '.join(missing[:-1])} or {missing[-1]}"
        raise SystemDependencyError(
            f"cannot compile the FMU '{name}' from its C sources (fishfmu compiles its built-in FMUs on the "
            f"machine, once): no {tools} found; install the Debian/Ubuntu package {BUILD_PACKAGE} "
            f"(apt-get install {BUILD_PACKAGE})")


def cmake_program() -> str:
    """CMake on PATH, else the one pip installed with fmpy (beside this Python: a venv need not be activated)."""
    found = shutil.which("cmake")
    if found:
        return found
    import cmake  # only without a cmake on PATH: the PyPI package fmpy depends on
    return str(Path(cmake.CMAKE_BIN_DIR) / "cmake")


def first_error_line(output: str, build_dir: Path) -> str:
    """What a compiler's or CMake's output says went wrong, in one line: the first line naming an
    error (for a "CMake Error at ...:", the first sentence of its message, spread over lines), else
    the first line; paths in the temporary build folder shortened to what is in the FMU.

    >>> out = "model.c: In function 'f':\\n/tmp/b/fmu/sources/model.c:3:1: error: expected ';'\\nmake: *** Error 1"
    >>> first_error_line(out, Path("/tmp/b"))
    "fmu/sources/model.c:3:1: error: expected ';'"
    >>> first_error_line("CMake Error at x.cmake:65 (message):\\n  The C compiler\\n\\n    cc\\n\\n  is not able to "
    ...                  "compile a simple test program.\\n\\n  It fails with ...", Path("/tmp/b"))
    'The C compiler cc is not able to compile a simple test program.'
    """
    lines = [line.strip() for line in output.replace(f"{build_dir.as_posix()}/", "").splitlines() if line.strip()]
    for i, line in enumerate(lines):
        if not re.search(r"\berror\b", line, re.IGNORECASE):
            continue
        if not line.startswith("CMake Error"):
            return line
        sentence = []
        for follow in lines[i + 1:i + 6]:
            sentence.append(follow)
            if follow.endswith("."):
                break
        return " ".join(sentence) or line
    return lines[0] if lines else "(no output)"


def _run(command: list[str], what: str, build_dir: Path) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True)
    except FileNotFoundError as exc:
        raise FmuBuildError(f"{what}: {command[0]} not found (CMake >= 3.15 and a C compiler are needed)") from exc
    if done.returncode != 0:  # stderr first: where the compiler says what is wrong; make's summary follows it
        raise FmuBuildError(f"{what} failed (exit code {done.returncode}): "
                            f"{first_error_line(done.stderr + chr(10) + done.stdout, build_dir)}")


def compile_binary(unzipped: Path, build_dir: Path, name: str | None = None) -> None:
    """Build binaries/<platform>/<id>.so with fmpy's CMake project (as ``fmpy compile`` does), output captured.

    Raises SystemDependencyError when the machine has no compiler or make (checked before CMake runs),
    FmuBuildError with the compiler's or CMake's first error line when the build fails."""
    name = name or unzipped.name
    require_build_tools(name)
    build_dir.mkdir(parents=True, exist_ok=True)
    create_cmake_settings(unzipped, build_dir, configuration="Release", all_warnings=True)
    source_dir = Path(fmpy.__file__).parent / "c-code"
    cmake = cmake_program()
    root = build_dir.parent
    _run([cmake, "-S", source_dir.as_posix(), "-B", build_dir.as_posix()], f"CMake configure of the FMU '{name}'", root)
    _run([cmake, "--build", build_dir.as_posix(), "--target", "install", "--config", "Release"],
         f"C build of the FMU '{name}'", root)
