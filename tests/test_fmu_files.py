"""Opening untrusted FMU files: every bad archive is an InputError naming the problem, and nothing
is left behind or written anywhere but the temporary folder (which is gone afterwards)."""

from __future__ import annotations

import os
import stat
import tempfile
import zipfile
from pathlib import Path

import pytest

from fishfmu.fmu.archive import OpenedFmu, open_fmu, require_variables
from plant.errors import InputError


@pytest.fixture()
def sandbox(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder holding the test's archives, with the process's temp dir inside it (``tmp/``)."""
    temp_root = tmp_path / "tmp"
    temp_root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp_root))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def listing(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*")}


def make_zip(path: Path, members: dict[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(path, "w", compression) as zf:
        for name, data in members.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=compression)
    return path


def fmu_members(fmu: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(fmu) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def assert_rejected(path: Path, sandbox: Path, *expected_words: str, **limits: int) -> InputError:
    """open_fmu raises InputError naming the problem; the temp folder is empty and nothing else appeared."""
    before = listing(sandbox)
    with pytest.raises(InputError) as failure:
        with open_fmu(path, **limits):
            pass
    assert listing(sandbox / "tmp") == set(), "temporary folder left behind"
    assert listing(sandbox) == before, "something was written outside the temporary folder"
    error = failure.value
    assert Path(error.file) == path
    for word in expected_words:
        assert word in str(error), (word, str(error))
    return error


# ---------------------------------------------------------------- not an FMU at all

def test_missing_file(sandbox: Path) -> None:
    assert_rejected(sandbox / "nowhere.fmu", sandbox, "not found")


def test_not_a_zip(sandbox: Path) -> None:
    path = sandbox / "text.fmu"
    path.write_text("just text\n" * 100)
    assert_rejected(path, sandbox, "not a zip archive")


def test_corrupt_zip_member(sandbox: Path) -> None:
    path = make_zip(sandbox / "corrupt.fmu", {"modelDescription.xml": b"A" * 1000}, zipfile.ZIP_STORED)
    data = path.read_bytes()
    path.write_bytes(data.replace(b"A" * 1000, b"B" * 1000, 1))  # contents no longer match the CRC
    assert_rejected(path, sandbox, "corrupt", "CRC")


def test_lying_size_header_is_caught(sandbox: Path) -> None:
    path = make_zip(sandbox / "liar.fmu", {"big.bin": bytes(200_000)})
    data = bytearray(path.read_bytes())
    # central directory entry: signature PK\1\2, uncompressed size at offset 24 (4 bytes, little endian)
    cd = data.rindex(b"PK\x01\x02")
    data[cd + 24:cd + 28] = (100).to_bytes(4, "little")
    local = data.index(b"PK\x03\x04")
    data[local + 22:local + 26] = (100).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    assert_rejected(path, sandbox, "big.bin")


# ---------------------------------------------------------------- dangerous members

@pytest.mark.parametrize("member, words", [
    ("../evil.txt", ("'../evil.txt'", "'..'")),
    ("resources/../../evil.txt", ("'resources/../../evil.txt'", "'..'")),
    ("/tmp/evil.txt", ("'/tmp/evil.txt'", "absolute path")),
    ("C:/evil.txt", ("'C:/evil.txt'", "absolute path")),
    ("resources\\..\\evil.txt", ("backslash",)),
])
def test_zip_slip_members_are_refused(sandbox: Path, member: str, words: tuple[str, ...]) -> None:
    path = make_zip(sandbox / "slip.fmu", {"modelDescription.xml": b"<x/>", member: b"evil"})
    assert_rejected(path, sandbox, *words)
    assert not (sandbox / "evil.txt").exists() and not Path("/tmp/evil.txt").exists()


def test_symlink_member_is_refused(sandbox: Path) -> None:
    path = sandbox / "link.fmu"
    with zipfile.ZipFile(path, "w") as zf:
        info = zipfile.ZipInfo("resources/passwd")
        info.create_system = 3
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, "/etc/passwd")
    assert_rejected(path, sandbox, "'resources/passwd'", "symbolic link")


def test_zip_bomb_is_refused_before_unpacking(sandbox: Path) -> None:
    path = make_zip(sandbox / "bomb.fmu", {"modelDescription.xml": b"<x/>", "zeros.bin": bytes(8 << 20)})
    assert path.stat().st_size < 100_000  # 8 MB of zeros compress to almost nothing
    assert_rejected(path, sandbox, "more than the limit of 1000000", max_unpacked_bytes=1_000_000)


def test_too_many_members_are_refused(sandbox: Path) -> None:
    path = make_zip(sandbox / "many.fmu", {f"resources/{k}.txt": b"" for k in range(50)})
    assert_rejected(path, sandbox, "50 members", max_members=20)


# ---------------------------------------------------------------- a zip, but not a usable FMU

def test_no_model_description(sandbox: Path) -> None:
    path = make_zip(sandbox / "empty.fmu", {"resources/readme.txt": b"hello"})
    assert_rejected(path, sandbox, "no modelDescription.xml")


def test_invalid_model_description(sandbox: Path) -> None:
    path = make_zip(sandbox / "invalid.fmu", {"modelDescription.xml": b"<fmiModelDescription fmiVersion='2.0'>"})
    assert_rejected(path, sandbox, "invalid modelDescription.xml")


def test_no_linux_binary(sandbox: Path, builtin_fmus: dict[str, Path]) -> None:
    members = {name: data for name, data in fmu_members(builtin_fmus["conveyor_drive"]).items()
               if not name.startswith("binaries/")}
    members["binaries/win64/conveyor_drive.dll"] = b"MZ"
    path = make_zip(sandbox / "windows_only.fmu", members)
    assert_rejected(path, sandbox, "no Linux binary binaries/linux64/conveyor_drive.so", "win64")


def test_model_exchange_only_fmu_is_refused(sandbox: Path, builtin_fmus: dict[str, Path]) -> None:
    members = fmu_members(builtin_fmus["conveyor_drive"])
    xml = members["modelDescription.xml"].decode()
    start, end = xml.index("<CoSimulation"), xml.index("</CoSimulation>") + len("</CoSimulation>")
    members["modelDescription.xml"] = (xml[:start] + '<ModelExchange modelIdentifier="conveyor_drive"/>'
                                       + xml[end:]).encode()
    path = make_zip(sandbox / "me_only.fmu", members)
    assert_rejected(path, sandbox, "no co-simulation interface")


# ---------------------------------------------------------------- a good FMU

def test_good_fmu_is_described_and_cleaned_up(sandbox: Path, builtin_fmus: dict[str, Path]) -> None:
    before = listing(sandbox)
    with open_fmu(builtin_fmus["conveyor_drive"]) as fmu:
        assert isinstance(fmu, OpenedFmu)
        assert fmu.unzip_dir.parent == sandbox / "tmp"
        assert (fmu.unzip_dir / "binaries/linux64/conveyor_drive.so").is_file()
        assert fmu.model_identifier == "conveyor_drive"
        speed = fmu.variables["belt_speed"]
        assert (speed.causality, speed.type, speed.unit) == ("output", "Real", "m/s")
        assert fmu.variables["speed_setpoint"].causality == "input"
        unzip_dir = fmu.unzip_dir
    assert not unzip_dir.exists()
    assert listing(sandbox) == before


def test_folder_is_removed_when_the_caller_fails(sandbox: Path, builtin_fmus: dict[str, Path]) -> None:
    with pytest.raises(RuntimeError):
        with open_fmu(builtin_fmus["singulation_controller"]):
            raise RuntimeError("the caller's own failure")
    assert listing(sandbox / "tmp") == set()


# ---------------------------------------------------------------- required variables

@pytest.mark.parametrize("wanted, words", [
    ({"belt_sped": ("output", "Real")}, ("no variable 'belt_sped'", "did you mean 'belt_speed'")),
    ({"belt_speed": ("input", "Real")}, ("'belt_speed' has causality 'output', expected 'input'",)),
    ({"jam": ("output", "Real")}, ("'jam' is of type Boolean, expected Real",)),
])
def test_missing_or_wrong_variables_are_named(sandbox: Path, builtin_fmus: dict[str, Path], wanted: dict,
                                              words: tuple[str, ...]) -> None:
    name = "singulation_controller" if "jam" in wanted else "conveyor_drive"
    with open_fmu(builtin_fmus[name]) as fmu:
        with pytest.raises(InputError) as failure:
            require_variables(fmu, wanted)
        require_variables(fmu, {"pe_1" if "jam" in wanted else "speed_setpoint":
                                ("input", "Boolean" if "jam" in wanted else "Real")})  # a right one passes
    assert Path(failure.value.file) == builtin_fmus[name]
    for word in words:
        assert word in str(failure.value)
    assert os.listdir(sandbox / "tmp") == []
