"""Fixtures shared by several test files."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def builtin_fmus() -> dict[str, Path]:
    """The built-in FMUs, built once into the FMU cache ($FISHFMU_CACHE or ~/.cache/fishfmu/fmus)."""
    from fishfmu.fmu_build import BUILTIN_FMUS, builtin_fmu
    return {name: builtin_fmu(name) for name in BUILTIN_FMUS}


@pytest.fixture(scope="session")
def unzipped_fmus(builtin_fmus: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each built-in FMU extracted once per session (fmpy's FMU2Slave runs from a folder)."""
    from fmpy import extract
    root = tmp_path_factory.mktemp("unzipped_fmus")
    return {name: Path(extract(str(path), str(root / name))) for name, path in builtin_fmus.items()}

