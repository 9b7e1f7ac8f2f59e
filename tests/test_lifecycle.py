"""One lifecycle for every command's folder (issue 30): ``run_info.json`` says ``running`` only while the command
runs; whatever ends it says how it ended (a bug: ``failed`` with the error, a signal: ``partial``), the same for
``run``, ``compare`` and ``diagnose``; and one stop mechanism (fishfmu/session.py) for a library call and a command.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from plant.errors import SimulationError

from fishfmu import commands
from fishfmu.session import raise_if_stopped, session, stop_between_steps

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
SHORT = {"fish.count": 2, "run.duration_s": 30.0, "run.stop_when_clear": False}


def info_of(out: Path) -> dict:
    return json.loads((out / "run_info.json").read_text())


def _bug(*args, **kwargs):
    raise ZeroDivisionError("a bug")


# ---------------------------------------------------------------- how a command ends, in its folder

def test_a_bug_in_a_run_leaves_its_folder_failed_not_running(tmp_path: Path, monkeypatch, builtin_fmus) -> None:
    import fishfmu.cosim.runner
    for module in (commands, fishfmu.cosim.runner):  # wherever the command finds it
        monkeypatch.setattr(module, "run_scenario", _bug, raising=False)
    with pytest.raises(ZeroDivisionError):
        commands.run(PAPER, tmp_path / "out", SHORT, report=False)
    info = info_of(tmp_path / "out")
    assert info["status"] == "failed" and info["error"] == "ZeroDivisionError: a bug", info
    assert info["command"] == "run" and info["scenario"] == str(PAPER)


@pytest.mark.parametrize("command", ["compare", "diagnose"])
def test_an_analysis_says_how_it_ended_as_a_run_does(tmp_path: Path, monkeypatch, command: str) -> None:
    import fishfmu.analysis.compare
    import fishfmu.analysis.diagnose
    data = tmp_path / "data"
    data.mkdir()
    dummy = SimpleNamespace(name="d", runs=[])
    monkeypatch.setattr(commands, "_dataset_and_params", lambda dataset, scenario: (dummy, None, None))
    for module, name in ((commands, "compare_dataset"), (fishfmu.analysis.compare, "compare_dataset"),
                         (commands, "diagnose_dataset"), (fishfmu.analysis.diagnose, "diagnose")):
        monkeypatch.setattr(module, name, _bug, raising=False)
    with pytest.raises(ZeroDivisionError):
        getattr(commands, command)(data, tmp_path / "bug")
    info = info_of(tmp_path / "bug")
    assert info["status"] == "failed" and info["error"] == "ZeroDivisionError: a bug" and info["command"] == command

    def blow_up(*args, **kwargs):
        raise SimulationError("numerical blow-up: fish 'f02' moves at 31.0 m/s", 2.35)

    for module, name in ((commands, "compare_dataset"), (fishfmu.analysis.compare, "compare_dataset"),
                         (commands, "diagnose_dataset"), (fishfmu.analysis.diagnose, "diagnose")):
        monkeypatch.setattr(module, name, blow_up, raising=False)
    with pytest.raises(SimulationError):
        getattr(commands, command)(data, tmp_path / "blow-up")
    info = info_of(tmp_path / "blow-up")
    assert info["status"] == "failed" and info["error"] == "at t = 2.350 s: numerical blow-up: fish 'f02' moves at " \
                                                          "31.0 m/s", info


# ---------------------------------------------------------------- one stop mechanism

def test_a_library_run_stops_after_the_step_a_signal_came_in(tmp_path: Path, builtin_fmus) -> None:
    """No session (a script): the run takes SIGTERM for itself, stops between two steps, writes what it has, and
    gives the signal back to the handler from before."""
    sent = []

    def signal_once(t: float, total: float) -> None:
        if not sent:
            sent.append(t)
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    done = commands.run(PAPER, tmp_path / "out", SHORT, report=False, on_progress=signal_once)
    assert done.result.status == "partial" and done.stop_exit_code == 143
    assert done.result.error.startswith("interrupted by SIGTERM at t = ")
    assert 0.0 < done.result.t_end_s < 1.0  # the first progress report is at the first step
    assert info_of(tmp_path / "out")["status"] == "partial"
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_second_signal_goes_to_the_handler_from_before_the_block() -> None:
    seen = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    try:
        with stop_between_steps() as stop:
            os.kill(os.getpid(), signal.SIGTERM)
            assert stop.requested and stop.signal_name == "SIGTERM" and seen == []
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_in_a_session_a_signal_a_stepping_loop_answered_is_not_raised_again(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    with session() as s:
        with stop_between_steps() as stop:
            os.kill(os.getpid(), signal.SIGINT)
            assert stop is s and stop.requested and stop.exit_code == 130
        raise_if_stopped()  # the run wrote what it had: the command goes on to print it


SECOND_SIGNAL = """
import os, signal, sys, time
from fishfmu.output.run_folder import RunFolder
from fishfmu.session import session
with session():
    with RunFolder.open(sys.argv[1], False, command="run") as folder, folder.stopping() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.requested
        print("asked to stop", flush=True)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(30)
        print("not stopped at once", flush=True)
"""


def test_a_second_signal_ends_the_command_at_once_with_its_folder_partial(tmp_path: Path) -> None:
    out = tmp_path / "out"
    child = subprocess.run([sys.executable, "-c", SECOND_SIGNAL, str(out)], capture_output=True, text=True,
                           timeout=60, env={**os.environ, "TMPDIR": str(tmp_path)})
    assert child.returncode == -signal.SIGTERM, child.stderr  # ended by the signal, as a shell sees it: 143
    assert child.stdout == "asked to stop\n" and "Traceback" not in child.stderr
    info = info_of(out)
    assert info["status"] == "partial" and info["stopped_by"] == "SIGTERM" and info["command"] == "run"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # the session's temporary folder is gone
