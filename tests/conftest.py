"""Fixtures shared by several test files."""

from __future__ import annotations

from pathlib import Path

import pytest

import fishfmu  # noqa: F401  first, so that its one-BLAS-thread default is set before any test module loads numpy


@pytest.fixture(scope="session")
def builtin_fmus() -> dict[str, Path]:
    """The built-in FMUs, built once into the FMU cache ($FISHFMU_CACHE or ~/.cache/fishfmu/fmus)."""
    from fishfmu.fmu.build import BUILTIN_FMUS, builtin_fmu
    return {name: builtin_fmu(name) for name in BUILTIN_FMUS}


@pytest.fixture(scope="session")
def unzipped_fmus(builtin_fmus: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each built-in FMU extracted once per session (fmpy's FMU2Slave runs from a folder)."""
    from fmpy import extract
    root = tmp_path_factory.mktemp("unzipped_fmus")
    return {name: Path(extract(str(path), str(root / name))) for name, path in builtin_fmus.items()}



FAULTY_FMU_SOURCES = Path(__file__).parent / "faulty_fmus" / "faulty_drive"


@pytest.fixture(scope="session")
def faulty_fmu() -> Path:
    """The test FMU that fails on purpose (tests/faulty_fmus/faulty_drive), built once into the FMU
    cache under the hash of its sources, as the built-in ones are."""
    import shutil
    import tempfile

    from fishfmu.fmu.build import build_fmu, cache_dir, source_digest
    final = cache_dir() / ("test-" + source_digest("faulty_drive", FAULTY_FMU_SOURCES)) / "faulty_drive.fmu"
    if not final.is_file():
        final.parent.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".faulty-", dir=final.parent.parent))
        try:
            build_fmu("faulty_drive", staging, model_dir=FAULTY_FMU_SOURCES)
            try:
                staging.rename(final.parent)
            except OSError:
                if not final.is_file():
                    raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return final
