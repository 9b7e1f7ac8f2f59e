"""FMU archives and FMU failures reported as what they are.

- an FMU whose modelIdentifier would load a library from outside its archive is refused (exit 2)
  and that library is never loaded, whether the check happens when the archive is opened or
  right before loading;
- an FMU failing in the very first step (or while it is initialised) fails the run like at any
  later step: exit 3, naming the FMU and the time, the run written with status "failed";
- NaN or infinity as an FMU parameter, an event value or a constant input is bad input (exit 2);
- a folder or a FIFO given as an FMU says what it is (a FIFO is never read, so nothing blocks);
- the FMU's own log message is part of the one-line error, in-process and in a worker;
- Booleans come out of an FMU as bool and Strings as str.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from plant.errors import InputError
from plant.contract.measured import read_dataset
from tests.test_faults import PAPER, faulty_overrides, write_scenario

from fishfmu.fmu.archive import open_fmu



def cli(*args: str, cwd: Path, timeout: float = 300) -> tuple[int, str]:
    """``fishfmu ARGS`` in a fresh process: (exit code, stderr)."""
    env = dict(os.environ, CI="true")
    proc = subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=timeout)
    return proc.returncode, proc.stderr


def one_line(err: str, prefix: str, *parts: str) -> str:
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(prefix), err
    for part in parts:
        assert part in lines[0], f"{part!r} not in {lines[0]!r}"
    return lines[0]


def with_drive_c1(path: Path, fmu: Path) -> Path:
    """The paper scenario, short, with drive_c1 (fmu[1]) from the file ``fmu``."""
    import tomllib

    import tomli_w
    data = tomllib.loads(PAPER.read_text())
    data["fmu"][1] = {"name": "drive_c1", "path": str(fmu)}
    data["fish"]["count"], data["run"]["duration_s"], data["expect"] = 1, 0.05, {}
    path.write_text(tomli_w.dumps(data))
    return path


# ---------------------------------------------------------------- 1. the library loaded is the archive's

EVIL_C = r"""
#include <fcntl.h>
#include <unistd.h>
__attribute__((constructor)) static void loaded(void) {
    int fd = open(MARKER, O_CREAT | O_WRONLY, 0644);
    if (fd >= 0) close(fd);
}
"""


@pytest.fixture()
def evil_library(tmp_path: Path) -> tuple[Path, Path]:
    """A shared library outside any archive that leaves a marker file when it is loaded: (library, marker)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    outside = tmp_path / "outside"
    outside.mkdir()
    marker = tmp_path / "LOADED"
    src = outside / "evil.c"
    src.write_text(EVIL_C)
    lib = outside / "evil.so"
    subprocess.run([cc, "-shared", "-fPIC", f'-DMARKER="{marker}"', "-o", str(lib), str(src)], check=True)
    return lib, marker


def with_model_identifier(fmu: Path, out: Path, identifier: str) -> Path:
    """A copy of ``fmu`` whose CoSimulation modelIdentifier is ``identifier`` (its binary left as it was)."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "modelDescription.xml":
                xml = data.decode()
                start = xml.index("<CoSimulation")
                old = 'modelIdentifier="conveyor_drive"'
                assert old in xml[start:]
                xml = xml[:start] + xml[start:].replace(old, f'modelIdentifier="{identifier}"', 1)
                data = xml.encode()
            dst.writestr(info, data)
    return out


def identifiers(evil: Path, tmp_path: Path) -> dict[str, str]:
    """modelIdentifiers that would make fmpy load ``evil`` (binaries/linux64/<id>.so joined to the unpack folder)."""
    up = "../" * (len(Path(tempfile_root()).resolve().parts) + 6)  # out of binaries/linux64 and the temp folder
    return {"absolute": str(evil.with_suffix("")), "dot-dot": up + str(evil.with_suffix("")).lstrip("/"),
            "separator": "sub/evil", "backslash": "sub\\evil", "odd characters": "evil;rm -rf"}


def tempfile_root() -> str:
    import tempfile
    return tempfile.gettempdir()


@pytest.mark.parametrize("case", ["absolute", "dot-dot", "separator", "backslash", "odd characters"])
def test_model_identifier_that_leads_out_of_the_archive_is_refused(case: str, tmp_path: Path, builtin_fmus,
                                                                    evil_library) -> None:
    evil, marker = evil_library
    identifier = identifiers(evil, tmp_path)[case]
    fmu = with_model_identifier(builtin_fmus["conveyor_drive"], tmp_path / "evil.fmu", identifier)
    with pytest.raises(InputError) as failure:
        with open_fmu(fmu):
            pass
    assert Path(failure.value.file) == fmu and "modelIdentifier" in str(failure.value)
    scenario = with_drive_c1(tmp_path / "evil.toml", fmu)
    code, err = cli("run", str(scenario), "--out", str(tmp_path / "out"), "--no-report", cwd=tmp_path)
    assert code == 2
    one_line(err, "error: ", "evil.fmu", "modelIdentifier")
    assert not marker.exists(), "the library outside the archive was loaded"
    assert not (tmp_path / "out").exists()


def test_library_is_checked_again_right_before_loading(tmp_path: Path, builtin_fmus, evil_library) -> None:
    """The archive's binary replaced by a link to a library outside after the archive was checked
    (or an OpenedFmu made up elsewhere): refused by resolved path, in-process and in a worker."""
    import copy
    import dataclasses

    from fishfmu.fmu.instance import InProcessFmu
    from fishfmu.fmu.worker import WorkerFmu
    evil, marker = evil_library
    with open_fmu(builtin_fmus["conveyor_drive"]) as fmu:
        binary = fmu.unzip_dir / "binaries" / "linux64" / "conveyor_drive.so"
        binary.unlink()
        binary.symlink_to(evil)
        with pytest.raises(InputError, match="outside the unpacked archive") as failure:
            InProcessFmu("drive", fmu, {})
        assert Path(failure.value.file) == builtin_fmus["conveyor_drive"]
        worker = WorkerFmu("drive", fmu, {})
        try:
            with pytest.raises(InputError, match="outside the unpacked archive"):
                worker.get([])
        finally:
            worker.terminate()
        md = copy.copy(fmu.model_description)
        md.coSimulation = copy.copy(md.coSimulation)
        md.coSimulation.modelIdentifier = str(evil.with_suffix(""))
        with pytest.raises(InputError, match="modelIdentifier"):
            InProcessFmu("drive", dataclasses.replace(fmu, model_description=md), {})
    assert not marker.exists(), "the library outside the archive was loaded"


# ---------------------------------------------------------------- 2. a fault in the first step

def assert_failed_run_written(out: Path, *in_error: str) -> dict:
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["status"] == "failed" and kpis["t_end_s"] == 0.0 and kpis["fish_in"] == 1 and kpis["lost"] == 1
    for part in in_error:
        assert part in kpis["error"]
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "failed" and info["error"] == kpis["error"]
    signals = pd.read_csv(out / "signals.csv")
    assert len(signals) == 0 and "drive_c1.belt_speed" in signals.columns
    run = read_dataset(out / "run").runs[0]  # the run in the measured-data format, readable: the line at t = 0
    assert len(run.fish) == 1 and (run.belts.t_s == 0.0).all() and (run.belts.speed_mps == 0.0).all()
    assert sorted(run.belts.conveyor_id) == ["c1", "c2", "c3", "c4"] and run.photoeyes.empty
    return kpis


@pytest.mark.parametrize("process", ["in-process", "worker"])
def test_fmu_error_in_the_first_step_exits_3_naming_fmu_time_and_its_message(faulty_fmu: Path, tmp_path: Path,
                                                                             process: str) -> None:
    overrides = faulty_overrides(faulty_fmu, 1, process)
    overrides["fmu"][0]["parameters"]["fault_time"] = 0.0
    scenario = write_scenario(tmp_path / "first.toml", overrides)
    out = tmp_path / "out"
    code, err = cli("run", str(scenario), "--out", str(out), "--no-report", cwd=tmp_path)
    assert code == 3, err
    expected = ("at t = 0.000 s: FMU 'drive_c1': doStep returned error: "
                '"faulty_drive: failing on purpose at t = 0 s"')
    one_line(err, "simulation failed: ", expected, str(out))
    assert_failed_run_written(out, expected)


def test_builtin_drive_given_an_out_of_range_setpoint_at_t0_names_it(tmp_path: Path) -> None:
    scenario = write_scenario(tmp_path / "event0.toml", {
        "fish.count": 1, "fish.first_drop_s": 0.0, "run.duration_s": 0.2, "expect": {},
        "event": [{"t_s": 0.0, "target": "drive_c1.speed_setpoint", "action": "override", "value": 9.0}]})
    out = tmp_path / "out"
    code, err = cli("run", str(scenario), "--out", str(out), cwd=tmp_path)  # with the report
    assert code == 3, err
    expected = ("at t = 0.000 s: FMU 'drive_c1': setReal returned error: "
                "\"fmi2SetReal: 'speed_setpoint' = 9 is outside its range [-2, 2]\"")
    one_line(err, "simulation failed: ", expected)
    assert_failed_run_written(out, expected)
    assert (out / "report.html").is_file()


def test_parameter_outside_its_declared_range_is_bad_input_before_the_fmu_sees_it(faulty_fmu: Path,
                                                                                  tmp_path: Path) -> None:
    overrides = faulty_overrides(faulty_fmu, 7, "in-process")  # fault is declared in [0, 5]
    scenario = write_scenario(tmp_path / "init.toml", overrides)
    out = tmp_path / "out"
    code, err = cli("run", str(scenario), "--out", str(out), "--no-report", cwd=tmp_path)
    assert code == 2, err
    one_line(err, f"error: {scenario}: fmu[0].parameters.fault: ", "fault = 7 is outside the range [0, 5]",
             "FMU 'drive_c1'")
    assert not out.exists()


def test_fmu_failing_while_initialised_fails_the_run_with_outputs(faulty_fmu: Path, tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """An FMU that refuses to initialise (any reason its own: here made so) is a failed run at t = 0,
    written like any failed run; the run's files hold the line as it was at t = 0."""
    from plant.errors import SimulationError

    from fishfmu.cosim import build, runner
    from fishfmu.output.run_folder import write_outputs
    from fishfmu.scenario.schema import load_scenario

    message = "FMU 'drive_c1': exitInitializationMode returned error: \"motor not configured\""

    def refuse(*_args, **_kwargs):
        raise SimulationError(message, 0.0)

    monkeypatch.setattr(build, "instantiate", refuse)
    result = runner.run_scenario(load_scenario(PAPER, faulty_overrides(faulty_fmu, 0, "in-process")))
    assert result.status == "failed" and message in result.error and result.t_end_s == 0.0
    write_outputs(result, tmp_path / "out", report=False)
    assert_failed_run_written(tmp_path / "out", message)


# ---------------------------------------------------------------- 3. NaN and infinity

@pytest.mark.parametrize("override, key", [
    ("fmu[0].parameters.fault_time=nan", "fmu[0].parameters.fault_time"),
    ("fmu[0].parameters.fault_time=inf", "fmu[0].parameters.fault_time"),
    ("wiring.inputs={\"drive_c1.speed_setpoint\"=-inf, \"plant.c2.speed\"=0.5, \"plant.c3.speed\"=0.8, "
     "\"plant.c4.speed\"=1.25}", "wiring.inputs.drive_c1.speed_setpoint"),
    ("event=[{t_s=0.0, target=\"drive_c1.speed_setpoint\", action=\"override\", value=nan}]", "event[0].value"),
    ("event=[{t_s=0.3, target=\"drive_c1.speed_setpoint\", action=\"bias\", value=inf}]", "event[0].value"),
], ids=["parameter nan", "parameter inf", "constant -inf", "event nan", "event inf"])
def test_nan_or_infinity_for_an_fmu_is_bad_input(faulty_fmu: Path, tmp_path: Path, override: str, key: str) -> None:
    scenario = write_scenario(tmp_path / "nan.toml", faulty_overrides(faulty_fmu, 0, "in-process"))
    code, err = cli("run", str(scenario), "--out", str(tmp_path / "out"), "--set", override, cwd=tmp_path)
    assert code == 2, err
    one_line(err, "error: ", "nan.toml", key, "finite number")
    assert not (tmp_path / "out").exists()


def test_nan_written_in_the_scenario_file_is_bad_input(tmp_path: Path) -> None:
    scenario = tmp_path / "nan.toml"
    scenario.write_text(PAPER.read_text().replace("speed_1 = 0.25", "speed_1 = nan"))
    code, err = cli("run", str(scenario), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert code == 2
    one_line(err, "error: ", "nan.toml", "fmu[0].parameters.speed_1", "finite number")


# ---------------------------------------------------------------- 4. a folder or a FIFO as the FMU

def test_folder_or_fifo_as_fmu_says_what_it_is_and_never_blocks(tmp_path: Path) -> None:
    folder = tmp_path / "drive.fmu"
    folder.mkdir()
    fifo = tmp_path / "pipe.fmu"
    os.mkfifo(fifo)
    link = tmp_path / "link.fmu"
    link.symlink_to(fifo)
    for path, words in [(folder, "is a directory, not an .fmu file"), (fifo, "is not a regular file (a FIFO"),
                        (link, "is not a regular file (a FIFO")]:
        with pytest.raises(InputError, match=words.replace("(", r"\(")) as failure:
            with open_fmu(path):
                pass
        assert Path(failure.value.file) == path
        scenario = with_drive_c1(tmp_path / "s.toml", path)
        code, err = cli("run", str(scenario), "--out", str(tmp_path / "out"), cwd=tmp_path, timeout=120)
        assert code == 2
        one_line(err, "error: ", path.name, words)


# ---------------------------------------------------------------- 5. the FMU's log in the error

def test_log_message_is_one_line_and_bounded() -> None:
    from fishfmu.fmu.instance import LOG_LINES, LOG_MESSAGE_CHARS, FmuLog
    log = FmuLog()
    for k in range(3 * LOG_LINES):
        log.add(0, b"logEvents", f"step {k}".encode())
    assert len(log.lines) == LOG_LINES and log.last_problem() is None  # plain messages are not problems
    since = log.count
    log.add(1, b"logStatusWarning", b"careful")
    log.add(3, b"logStatusError", b"broken\n  over\ttwo lines " + b"x" * 1000 + b"\xff")
    log.add(1, b"logStatusWarning", b"a later warning")
    said = log.last_problem(since)
    assert said.startswith("broken over two lines xxx") and "\n" not in said  # the error, not the later warning
    assert len(said) == LOG_MESSAGE_CHARS and said.endswith("...")
    assert log.last_problem(log.count) is None  # nothing logged during a later call


# ---------------------------------------------------------------- 6. Booleans and Strings

def test_booleans_come_out_of_an_fmu_as_bool_in_process_and_in_a_worker(builtin_fmus) -> None:
    from fishfmu.fmu.instance import InProcessFmu
    from fishfmu.fmu.worker import WorkerFmu
    with open_fmu(builtin_fmus["singulation_controller"]) as fmu:
        for instance in (InProcessFmu("c", fmu, {}), WorkerFmu("c", fmu, {})):
            try:
                instance.set({"pe_1": True})
                instance.do_step(0.0, 0.01)
                values = instance.get(["jam", "holding_1"])
            finally:
                instance.terminate()
            assert values == {"jam": False, "holding_1": False}
            assert all(type(v) is bool for v in values.values()), values


def test_strings_pass_as_str_and_booleans_as_bool(builtin_fmus) -> None:
    """fmpy's getString gives bytes and fmi2GetBoolean C ints; an FMU instance gives str and bool."""
    from fishfmu.fmu.archive import FmuVariable
    from fishfmu.fmu.instance import InProcessFmu

    class Slave:  # stands in for fmpy's FMU2Slave
        def __init__(self) -> None:
            self.strings: dict[int, bytes] = {1: "grüß".encode()}
            self.booleans: dict[int, int] = {2: 1}

        getReal = getInteger = None  # noqa: N815 (not used here)

        def getString(self, vrs):  # noqa: N802 (fmpy's names)
            return [self.strings[v] for v in vrs]

        def setString(self, vrs, values):  # noqa: N802
            assert all(isinstance(v, str) for v in values)  # fmpy encodes str itself
            self.strings.update({v: s.encode() for v, s in zip(vrs, values)})

        component = None  # FMI 2 booleans go to the C functions, the value references made once

        def fmi2GetBoolean(self, c, vrs, n, values):  # noqa: N802
            for i in range(n):
                values[i] = self.booleans[vrs[i]]

        def fmi2SetBoolean(self, c, vrs, n, values):  # noqa: N802
            self.booleans.update((vrs[i], values[i]) for i in range(n))

    with open_fmu(builtin_fmus["conveyor_drive"]) as fmu:
        instance = InProcessFmu("d", fmu, {})
        instance.terminate()
    instance._slave = Slave()
    instance._batch_cache.clear()
    instance.variables = {"label": FmuVariable("label", "output", "String", "discrete", 1, None, None),
                          "on": FmuVariable("on", "output", "Boolean", "discrete", 2, None, None)}
    assert instance.get(["label", "on"]) == {"label": "grüß", "on": True}
    assert type(instance.get(["on"])["on"]) is bool
    instance.set({"label": b"bytes in", "on": 0})
    assert instance.get(["label", "on"]) == {"label": "bytes in", "on": False}
