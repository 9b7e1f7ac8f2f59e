"""Two commands on one output folder (issue 39, item 1): the second is refused at once, the first keeps its result.

Each case starts a first command in a process of its own and waits until it has made its folder
(``run_info.json`` says ``running``: the folder is locked by then), starts the second on the same folder, then
stops the first by a signal (it runs long on purpose, so that it is certainly still running when the second
starts: no timing in the assertions).  Before the lock, the second removed the first's files while the first
wrote them: both exited normally, the first's result was gone and every later ``--overwrite`` was refused,
blaming the user.  A lock dies with its process: a folder a ``kill -9`` left is taken again at once.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from plant.errors import InputError

from fishfmu.output import lock, ownership

ROOT = Path(__file__).resolve().parents[1]
RD = str(ROOT / "scenarios" / "reject_doubles.toml")
SHORT = ["--set", "fish.count=5", "--no-report"]
LONG = ["--set", "run.duration_s=3000", "--set", "run.stop_when_clear=false", *SHORT]
"""still running when the second command comes, on a loaded machine too: without ``stop_when_clear=false`` the five
fish leave the line after 27 s of simulated time (4.5 s of wall time), sooner than a second Python starts under load"""


def start(args: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fishfmu.cli", *args], cwd=ROOT, start_new_session=True,
                            env={**os.environ, "CI": "1"}, stdout=subprocess.DEVNULL, stderr=open(log, "wb"))


def fishfmu(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "CI": "1"}, timeout=600)


def wait_running(proc: subprocess.Popen, out: Path, log: Path, timeout_s: float = 120.0) -> None:
    """Until ``out/run_info.json`` says running (the command holds the folder)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()
        try:
            if json.loads((out / "run_info.json").read_text())["status"] == "running":
                return
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.2)
    raise AssertionError(f"{out} not running within {timeout_s} s")


def stop(proc: subprocess.Popen, signum: int) -> int:
    os.killpg(proc.pid, signum)
    try:
        return proc.wait(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise


def refused_in_use(done: subprocess.CompletedProcess, out: Path, first: subprocess.Popen) -> None:
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert str(out) in lines[0] and "in use by" in lines[0] and f"pid {first.pid}" in lines[0], lines[0]
    assert "killed?" not in lines[0]


def test_a_second_run_on_a_folder_in_use_is_refused_and_the_first_keeps_its_result(tmp_path):
    out = tmp_path / "x"
    log = tmp_path / "first.txt"
    first = start(["run", RD, "--out", str(out), *LONG, "--overwrite", "--seed", "1"], log)
    try:
        wait_running(first, out, log)
        second = fishfmu("run", RD, "--out", str(out), "--set", "run.duration_s=2", *SHORT, "--overwrite",
                         "--seed", "2")
        refused_in_use(second, out, first)
    finally:
        rc = stop(first, signal.SIGTERM)
    assert rc == 143, log.read_text()
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "partial" and info["seed"] == 1  # the first's result, whole
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["status"] == "partial" and kpis["t_end_s"] > 0
    assert ownership.first_foreign(out) is None  # every file is listed in the manifest: replaceable
    again = fishfmu("run", RD, "--out", str(out), "--set", "run.duration_s=2", *SHORT, "--overwrite", "--seed", "3")
    assert again.returncode in (0, 1), again.stderr
    assert json.loads((out / "run_info.json").read_text())["seed"] == 3


def test_a_second_identical_sweep_is_refused_and_the_folder_resumes(tmp_path):
    out = tmp_path / "sweep"
    log = tmp_path / "first.txt"
    sweep = ["sweep", RD, "--seeds", "1", "--param", "fish.count=2,3", "--set", "run.duration_s=3000",
             "--set", "run.stop_when_clear=false",
             "--workers", "1", "--out", str(out)]
    first = start(sweep, log)
    try:
        wait_running(first, out, log)
        second = fishfmu(*sweep)
        refused_in_use(second, out, first)
    finally:
        rc = stop(first, signal.SIGINT)
    assert rc == 130, log.read_text()
    assert json.loads((out / "run_info.json").read_text())["status"] == "partial"
    assert ownership.first_foreign(out) is None
    resumed = fishfmu(*sweep, "--max-runs", "0")  # the same command resumes the folder (running nothing more)
    assert resumed.returncode == 0, resumed.stderr
    assert not [p.name for p in out.rglob("*.part")], "temporary files left in the sweep folder"


def test_a_folder_left_by_kill_9_is_not_locked(tmp_path):
    out = tmp_path / "x"
    log = tmp_path / "first.txt"
    first = start(["run", RD, "--out", str(out), *LONG], log)
    wait_running(first, out, log)
    assert stop(first, signal.SIGKILL) == -signal.SIGKILL
    kept = fishfmu("run", RD, "--out", str(out), "--set", "run.duration_s=2", *SHORT)
    assert kept.returncode == 2 and "did not finish (killed?)" in kept.stderr, kept.stderr  # now said truly
    again = fishfmu("run", RD, "--out", str(out), "--set", "run.duration_s=2", *SHORT, "--overwrite")
    assert again.returncode in (0, 1), again.stderr
    assert json.loads((out / "run_info.json").read_text())["status"] == "ok"


def test_the_lock_is_the_folders_and_is_let_go_at_the_end(tmp_path):
    """In one process: taken again is a no-op; another open of the folder (another command) is refused naming
    this process; closing the command's manifest lets it go."""
    out = tmp_path / "o"
    ownership.prepare_out_dir(out, overwrite=False, command="run")
    assert lock.holds(out)
    probe = subprocess.run([sys.executable, "-c", "import sys; from fishfmu.output import lock\n"
                            f"lock.acquire({str(out)!r})"], capture_output=True, text=True, cwd=ROOT)
    assert probe.returncode == 1 and f"in use by another fishfmu command (pid {os.getpid()}" in probe.stderr, \
        probe.stderr
    assert not list(out.glob("*lock*")), "the lock writes nothing into the folder"
    from fishfmu.output import manifest
    manifest.close(out)
    assert not lock.holds(out)
    free = subprocess.run([sys.executable, "-c", "from fishfmu.output import lock\n"
                           f"lock.acquire({str(out)!r})"], capture_output=True, text=True, cwd=ROOT)
    assert free.returncode == 0, free.stderr


def test_a_single_file_output_takes_its_folders_lock(tmp_path):
    """``--junit``, ``bench --json``: the folder's manifest records the file at the end, so one command at a time
    writes into that folder; a refusal lets the lock go again."""
    target = tmp_path / "bench.json"
    ownership.check_single_file_target(target)
    assert lock.holds(tmp_path)
    probe = subprocess.run([sys.executable, "-c", "from fishfmu.output import ownership\n"
                            f"ownership.check_single_file_target({str(tmp_path / 'other.json')!r})"],
                           capture_output=True, text=True, cwd=ROOT)
    assert probe.returncode == 1 and "in use by another fishfmu command" in probe.stderr, probe.stderr
    from fishfmu.output import manifest
    manifest.close(tmp_path)
    assert not lock.holds(tmp_path)
    (tmp_path / "user.json").write_text("{}")
    with pytest.raises(InputError, match="was not written by fishfmu"):
        ownership.check_single_file_target(tmp_path / "user.json")
    assert not lock.holds(tmp_path)
