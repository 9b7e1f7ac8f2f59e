"""SSP archives, bare SSD files and parameter files as a hostile user writes them (issue 28): each is bad input,
exit 2 with one line naming the SSP (or parameter file) and the component, connection or parameter, found
before anything large is read or copied; a FIFO is never opened.

The systems are built from the built-in conveyor-drive FMU: the paper's scenario with its fourth drive
brought in by the SSP instead of its own ``[[fmu]]`` (a system that checks; each case breaks one thing).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
import tomli_w

from plant.errors import InputError

from fishfmu.scenario.schema import MAX_FMUS, load_scenario
from fishfmu.scenario.ssp import MAX_SSP_BYTES, read_ssp
from tests.test_bad_input import PAPER, assert_one_clear_line, run_main, sandbox  # noqa: F401 (a fixture)

ROOT = Path(__file__).parents[1]
SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="drives"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssd:System name="drives">
    <ssd:Elements>{components}
    </ssd:Elements>{connections}
  </ssd:System>
</ssd:SystemStructureDescription>
"""


def ssd(components: dict[str, str], connections: str = "", binding: str = "") -> str:
    """An SSD of FMU components (name -> source); ``binding``: a ParameterBindings element for the last one."""
    items = [f'\n      <ssd:Component name="{n}" source="{s}">{binding if i == len(components) - 1 else ""}'
             "</ssd:Component>" for i, (n, s) in enumerate(components.items())]
    return SSD.format(components="".join(items),
                      connections=f"\n    <ssd:Connections>{connections}</ssd:Connections>" if connections else "")


def link(factor: str) -> str:
    return ('<ssd:Connection startElement="spare" startConnector="belt_speed" endElement="drive_c4" '
            f'endConnector="load_force"><ssc:LinearTransformation factor="{factor}" offset="0"/></ssd:Connection>')


def archive(folder: Path, drive: Path, text: str, members: dict[str, bytes] | None = None) -> Path:
    path = folder / "drives.ssp"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("SystemStructure.ssd", text)
        zf.write(drive, "resources/drive.fmu")
        for name, data in (members or {}).items():
            zf.writestr(name, data)
    return path


def scenario(folder: Path, ssp: str | None = None, **fmu_entry) -> Path:
    """The paper's scenario, 2 fish; drive_c4 from ``ssp`` when given, else its own [[fmu]] updated with
    ``fmu_entry``."""
    doc = tomllib.loads(PAPER.read_text())
    doc["fish"]["count"] = 2
    if ssp is not None:
        doc["fmu"] = [f for f in doc["fmu"] if f["name"] != "drive_c4"]
        doc["system"] = {"ssp": ssp}
    else:
        doc["fmu"][-1].update(fmu_entry)
    path = folder / "scenario.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def check(sandbox: Path, capsys, monkeypatch, path: Path) -> tuple[int, str]:
    return run_main(sandbox, capsys, monkeypatch, "check", str(path))


def test_an_ssp_bringing_the_fourth_drive_checks(sandbox, capsys, monkeypatch, builtin_fmus):
    """The control case: the system every other case breaks in one place is good."""
    archive(sandbox, builtin_fmus["conveyor_drive"], ssd({"drive_c4": "resources/drive.fmu"}))
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    assert code == 0, err


@pytest.mark.parametrize("factor", ["NaN", "INF", "-INF", "1e400"])
def test_a_linear_transformation_that_is_not_finite_is_refused_naming_the_connection(factor, sandbox, capsys,
                                                                                       monkeypatch, builtin_fmus):
    text = ssd({"spare": "resources/drive.fmu", "drive_c4": "resources/drive.fmu"}, link(factor))
    archive(sandbox, builtin_fmus["conveyor_drive"], text)
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    assert_one_clear_line(code, err, str(sandbox / "drives.ssp"), "connection spare.belt_speed -> drive_c4.load_force",
                          f"factor '{factor}' is not a finite number")


@pytest.mark.parametrize("line, shown", [
    ("drum_radius = inf", "inf is not a finite number"),
    ("drum_radius = 1e400", "inf is not a finite number"),
    ("drum_radius = 1979-05-27T07:32:00Z", "is a datetime"),
    ("drum_radius = 1979-05-27", "is a date"),
    ("drum_radius = 99999999999999999999999", "outside the 64-bit integer range"),
])
def test_a_parameter_file_value_that_no_fmu_takes_is_refused_naming_file_and_parameter(line, shown, sandbox, capsys,
                                                                                       monkeypatch):
    (sandbox / "drive.toml").write_text(line + "\n")
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, parameter_file="drive.toml"))
    assert_one_clear_line(code, err, f"{sandbox / 'drive.toml'}: drum_radius: ", shown)


@pytest.mark.parametrize("value", ["NaN", "INF", "1e400"])
def test_an_ssv_value_that_is_not_finite_is_refused_naming_file_and_parameter(value, sandbox, capsys, monkeypatch):
    (sandbox / "drive.ssv").write_text(
        '<ssv:ParameterSet version="1.0" name="d" xmlns:ssv="http://ssp-standard.org/SSP1/'
        f'SystemStructureParameterValues"><ssv:Parameters><ssv:Parameter name="drum_radius"><ssv:Real value="{value}"/>'
        "</ssv:Parameter></ssv:Parameters></ssv:ParameterSet>")
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, parameter_file="drive.ssv"))
    assert_one_clear_line(code, err, str(sandbox / "drive.ssv"), "parameter 'drum_radius'", "not a finite number")


def test_a_bare_ssd_whose_parameter_file_is_a_fifo_is_refused_without_opening_it(tmp_path, builtin_fmus):
    folder = tmp_path / "system"
    folder.mkdir()
    (folder / "drive.fmu").write_bytes(builtin_fmus["conveyor_drive"].read_bytes())
    os.mkfifo(folder / "drive.ssv")  # opening it for reading would wait for a writer for ever
    binding = '<ssd:ParameterBindings><ssd:ParameterBinding source="drive.ssv"/></ssd:ParameterBindings>'
    (folder / "drives.ssd").write_text(ssd({"drive_c4": "drive.fmu"}, binding=binding))
    path = scenario(tmp_path, "system/drives.ssd")
    done = subprocess.run([sys.executable, "-m", "fishfmu.cli", "check", str(path)], capture_output=True, text=True,
                          timeout=60, cwd=ROOT, env={**os.environ, "CI": "1"})
    assert_one_clear_line(done.returncode, done.stderr, str(folder / "drives.ssd"), "component 'drive_c4'",
                          "'drive.ssv' is not a regular file (a FIFO (named pipe))")


@pytest.mark.parametrize("source", ["file:drive.fmu", "file:///{folder}/drive.fmu", "{folder}/drive.fmu",
                                    "../drive.fmu", "sub/../../drive.fmu", "%2E%2E/drive.fmu", "link.fmu"])
def test_a_bare_ssd_takes_only_relative_sources_inside_its_folder(source, sandbox, capsys, monkeypatch,
                                                                   builtin_fmus):
    folder = sandbox / "system"
    (folder / "sub").mkdir(parents=True)
    for where in (sandbox, folder):
        (where / "drive.fmu").write_bytes(builtin_fmus["conveyor_drive"].read_bytes())
    (folder / "link.fmu").symlink_to(sandbox / "drive.fmu")  # a link inside the folder that leads out of it
    (folder / "drives.ssd").write_text(ssd({"drive_c4": source.format(folder=folder)}))
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "system/drives.ssd"))
    line = assert_one_clear_line(code, err, str(folder / "drives.ssd"), "component 'drive_c4': source")
    assert "only relative paths inside it" in line or "only relative paths inside the SSD's folder" in line, line


def test_ssp_components_count_towards_the_limit_of_fmus_before_any_is_copied(sandbox, capsys, monkeypatch,
                                                                            builtin_fmus, tmp_path_factory):
    n = MAX_FMUS - 4 + 1  # the scenario keeps 4 FMUs of its own: one too many
    text = ssd({f"extra_{i}": "resources/drive.fmu" for i in range(n)})
    path = archive(sandbox, builtin_fmus["conveyor_drive"], text)
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    assert_one_clear_line(code, err, str(path), f"the system has {n} components", "room for 60 more FMUs")
    cache = tmp_path_factory.mktemp("cache")
    monkeypatch.setenv("FISHFMU_CACHE", str(cache))
    with pytest.raises(InputError, match="room for 60 more"):
        read_ssp(path, 60)
    assert list(cache.iterdir()) == []  # nothing copied out of the archive


def test_an_ssp_larger_than_the_limit_is_refused_before_it_is_read(sandbox, capsys, monkeypatch):
    path = sandbox / "drives.ssp"
    with open(path, "wb") as fh:
        fh.truncate(MAX_SSP_BYTES + 1)  # sparse: no gigabyte written
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    assert_one_clear_line(code, err, str(path), f"at most {MAX_SSP_BYTES >> 20} MB")


def test_an_ssp_member_is_streamed_not_held_in_memory(tmp_path, builtin_fmus):
    """A 200 MB component (zeros: 200 kB in the archive) is copied into the cache in chunks: the process grows
    by far less than the member (read whole, it would grow by at least 200 MB)."""
    member_bytes = 200 << 20
    for name, size in (("small.ssp", 1 << 20), ("big.ssp", member_bytes)):
        with zipfile.ZipFile(tmp_path / name, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", ssd({"big": "resources/big.fmu"}))
            with zf.open("resources/big.fmu", "w", force_zip64=True) as out:
                for _ in range(size >> 20):
                    out.write(bytes(1 << 20))
    # VmHWM: the peak resident size of this process's memory (ru_maxrss would carry the forking parent's over exec);
    # the small archive first, so that what read_ssp imports is in memory before the big one is measured
    code = ("import sys; from pathlib import Path; from fishfmu.scenario.ssp import read_ssp\n"
            "peak = lambda: int(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:')))\n"
            "read_ssp(Path(sys.argv[1]))\n"
            "before = peak(); system = read_ssp(Path(sys.argv[2])); print(peak() - before, system.components[0].fmu)")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "small.ssp"), str(tmp_path / "big.ssp")],
                          capture_output=True, text=True, timeout=120,
                          cwd=ROOT,
                          env={**os.environ, "FISHFMU_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    grown_kib, copy = done.stdout.split()
    assert int(grown_kib) < 50 * 1024, f"grew by {int(grown_kib) >> 10} MB reading a {member_bytes >> 20} MB member"
    assert Path(copy).stat().st_size == member_bytes


def test_an_error_about_a_components_fmu_names_the_ssp_and_component_not_the_cache(sandbox, capsys, monkeypatch,
                                                                                  builtin_fmus):
    text = ssd({"drive_c4": "resources/broken.fmu"})
    path = archive(sandbox, builtin_fmus["conveyor_drive"], text, {"resources/broken.fmu": b"not a zip file"})
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    line = assert_one_clear_line(code, err, f"error: {path}: ", "component 'drive_c4' (source 'resources/broken.fmu')",
                                 "not a zip archive")
    assert ".cache" not in line and "/ssp/" not in line, line


def test_a_connector_name_fishfmu_cannot_wire_is_refused_naming_the_ssp(sandbox, capsys, monkeypatch, builtin_fmus):
    conn = ('<ssd:Connection startElement="spare" startConnector="belt speed" endElement="drive_c4" '
            'endConnector="load_force"/>')
    path = archive(sandbox, builtin_fmus["conveyor_drive"],
                   ssd({"spare": "resources/drive.fmu", "drive_c4": "resources/drive.fmu"}, conn))
    code, err = check(sandbox, capsys, monkeypatch, scenario(sandbox, "drives.ssp"))
    assert_one_clear_line(code, err, str(path), "connection spare.belt speed -> drive_c4.load_force",
                          "'spare.belt speed' is not a '<component>.<variable>' name")


def test_ssp_parameter_values_keep_their_types_through_the_loader(tmp_path, builtin_fmus):
    """An SSV binding's Real reaches the FMU entry as a float (and the file is read once for many loads)."""
    binding = ('<ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues><ssv:ParameterSet version="1.0" '
               'name="p"><ssv:Parameters><ssv:Parameter name="drum_radius"><ssv:Real value="0.25"/></ssv:Parameter>'
               "</ssv:Parameters></ssv:ParameterSet></ssd:ParameterValues></ssd:ParameterBinding>"
               "</ssd:ParameterBindings>")
    archive(tmp_path, builtin_fmus["conveyor_drive"], ssd({"drive_c4": "resources/drive.fmu"}, binding=binding))
    sc = load_scenario(scenario(tmp_path, "drives.ssp"))
    entry = next(f for f in sc.fmu if f.name == "drive_c4")
    assert entry.parameters == {"drum_radius": 0.25} and entry.ssp_source == (str(tmp_path / "drives.ssp"),
                                                                              "resources/drive.fmu")
