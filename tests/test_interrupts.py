"""SIGTERM / Ctrl-C to the commands that start worker processes (issue 13).

Each case runs the command in a process of its own (a new session, as a shell job), waits until
its worker processes are up, sends the signal and checks: exit code 143 (SIGTERM) or 130
(SIGINT), ``run_info.json`` says ``partial``, none of the command's processes is left, and the
temporary folder (``TMPDIR``) holds nothing new: no unpacked FMUs, no Dask scratch space.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from fishfmu.session import Interrupted, deferred_signals, session

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = str(ROOT / "scenarios" / "paper_dump.toml")
LONG_RUNS = ["--set", "run.duration_s=30", "--set", "run.stop_when_clear=false"]  # still running when signalled


def launch(args: list[str], tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp), "CI": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "fishfmu.cli", *args], cwd=ROOT, env=env, start_new_session=True,
                            stdout=open(tmp_path / "stdout.txt", "wb"), stderr=open(tmp_path / "stderr.txt", "wb"))
    return proc, tmp


def workers_of(proc: subprocess.Popen) -> list[psutil.Process]:
    try:
        return [p for p in psutil.Process(proc.pid).children(recursive=True)
                if "spawn_main" in " ".join(p.cmdline())]
    except psutil.Error:
        return []


def wait_for_workers(proc: subprocess.Popen, n: int, timeout_s: float = 60.0) -> list[psutil.Process]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the command ended before its workers started"
        if len(workers_of(proc)) >= n:
            time.sleep(1.5)  # the workers take their first tasks
            return psutil.Process(proc.pid).children(recursive=True)
        time.sleep(0.2)
    raise AssertionError(f"no {n} worker processes within {timeout_s} s")


def stop(proc: subprocess.Popen, signum: int, group: bool, tmp_path: Path) -> tuple[int, str]:
    """Signal the command (or its whole process group, as Ctrl-C in a terminal) and wait for it."""
    if group:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    try:
        rc = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    return rc, (tmp_path / "stderr.txt").read_text()


def assert_nothing_left(children: list[psutil.Process], tmp: Path) -> None:
    deadline = time.monotonic() + 5.0
    alive = children
    while alive and time.monotonic() < deadline:
        alive = [p for p in children if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
        time.sleep(0.2)
    for p in alive:
        p.kill()
    assert not alive, f"processes left behind: {[' '.join(p.cmdline())[:80] for p in alive]}"
    assert sorted(p.name for p in tmp.iterdir()) == [], "temporary files left behind"


def run_info(folder: Path) -> dict:
    return json.loads((folder / "run_info.json").read_text())


def test_run_seeds_sigterm_stops_workers_and_marks_the_folder_partial(tmp_path):
    out = tmp_path / "out"
    proc, tmp = launch(["run", SCENARIO, "--seeds", "3", "--set", "fish.count=2", *LONG_RUNS, "--workers", "2",
                        "--out", str(out)], tmp_path)
    children = wait_for_workers(proc, 2)
    rc, err = stop(proc, signal.SIGTERM, False, tmp_path)
    assert rc == 143, err
    assert "no run finished" not in err and "internal error" not in err and "Traceback" not in err, err
    assert "stopped: by SIGTERM" in err
    info = run_info(out)
    assert info["status"] == "partial" and info["stopped_by"] == "SIGTERM"
    assert_nothing_left(children, tmp)


def test_sweep_ctrl_c_to_the_process_group_keeps_the_folder_resumable(tmp_path):
    out = tmp_path / "sweep"
    proc, tmp = launch(["sweep", SCENARIO, "--seeds", "1", "--param", "fish.count=1,2", *LONG_RUNS,
                        "--workers", "2", "--out", str(out)], tmp_path)
    children = wait_for_workers(proc, 2)
    rc, err = stop(proc, signal.SIGINT, True, tmp_path)
    assert rc == 130, err
    assert "Traceback" not in err, err
    info = run_info(out)
    assert info["status"] == "partial" and info["stopped_by"] == "SIGINT" and info["n_runs"] == 2
    assert (out / "sweep.json").is_file() and (out / "runs.csv").is_file()  # the same command resumes
    assert_nothing_left(children, tmp)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from plant.contract.line import KpiSettings
    from plant.contract.measured import Dataset, Run, write_dataset
    from plant.sim.simulate import simulate_plant

    from tests.plant_helpers import fish, straight_line
    line = straight_line(("c1", 0.0, 1.5, 0.0), ("c2", 1.51, 1.5, -0.02),
                         photoeyes=(("pe_a", 1.4, 0.015), ("pe_b", 2.9, -0.005)))
    fishes = [fish("f01", 0.6, x_m=0.4, y_m=0.05, t_s=0.3), fish("f02", 0.5, x_m=0.4, y_m=-0.08, t_s=1.3)]
    sim = simulate_plant(line, fishes, {"c1": 0.6, "c2": 1.0}, 8.0)
    runs = [Run(f"r{i}", 24.0, "copy", sim.fish, sim.tracks, sim.photoeyes, sim.belts) for i in range(6)]
    root = tmp_path_factory.mktemp("interrupt_data") / "six"
    write_dataset(Dataset("six", "six copies of one two-fish run", line, KpiSettings(outfeed_photoeye="pe_b"), runs),
                  root)
    return root


def test_compare_sigterm_stops_its_pool_and_writes_the_runs_that_finished(tmp_path, dataset):
    out = tmp_path / "cmp"
    proc, tmp = launch(["compare", str(dataset), "--workers", "2", "--out", str(out)], tmp_path)
    children = wait_for_workers(proc, 2)
    rc, err = stop(proc, signal.SIGTERM, False, tmp_path)
    assert rc == 143, err
    assert "Traceback" not in err, err
    info = run_info(out)
    assert info["status"] == "partial" and info["stopped_by"] == "SIGTERM"
    if (out / "compare.json").is_file():  # stopped while re-simulating: the rest are listed
        failed = json.loads((out / "compare.json").read_text())["failed"]
        assert all("stopped by SIGTERM" in e for e in failed.values())
    assert_nothing_left(children, tmp)


def wait_for_cpu(proc: subprocess.Popen, cpu_s: float, timeout_s: float = 120.0) -> None:
    """Until the command has used ``cpu_s`` of CPU (past its imports: re-simulating)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the command ended before it was signalled"
        try:
            t = psutil.Process(proc.pid).cpu_times()
        except psutil.Error:
            t = None
        if t is not None and t.user + t.system >= cpu_s:
            return
        time.sleep(0.1)
    raise AssertionError(f"no {cpu_s} s of CPU within {timeout_s} s")


@pytest.mark.parametrize("command", ["compare", "diagnose", "calibrate"])
def test_ctrl_c_to_the_group_while_re_simulating_in_the_command_is_exit_130(tmp_path, dataset, command):
    """Issue 39, item 6: with one worker the runs are re-simulated in the command's own process; a Ctrl-C that
    came while Exudyn's step ran Python code came out of it as a SystemError: exit 4, ``failed``."""
    out = tmp_path / "o"
    proc, tmp = launch([command, str(dataset), "--workers", "1", "--out", str(out)], tmp_path)
    wait_for_cpu(proc, 3.0)  # past the imports (about 2 s), re-simulating; compare is done by about 6 s
    rc, err = stop(proc, signal.SIGINT, True, tmp_path)
    assert rc == 130, err
    assert "internal error" not in err and "SystemError" not in err and "Traceback" not in err, err
    assert "stopped: by SIGINT" in err
    info = run_info(out)
    assert info["status"] == "partial" and info["stopped_by"] == "SIGINT", info


def test_a_signal_raised_inside_exudyns_step_is_the_signal_not_a_bug(monkeypatch):
    """What Exudyn gives back when the session's handler raised in Python code its step called: a SystemError
    whose cause is the signal's exception.  The re-simulations in the command's process stop by the signal, with
    what finished."""
    from fishfmu.analysis import resim

    def task(args):  # noqa: ANN001, ANN202
        if args[1] == "second":
            raise SystemError("<built-in method SolveSteps> returned a result with an exception set") \
                from Interrupted(signal.SIGINT)
        return "done"

    monkeypatch.setattr(resim, "_task", task)
    with pytest.raises(Interrupted) as stopped:
        resim.resimulate_many(None, ["first", "second", "third"], [None] * 3, workers=1)
    assert stopped.value.signum == signal.SIGINT and stopped.value.partial == ["done", None, None]
    monkeypatch.setattr(resim, "_task", lambda args: (_ for _ in ()).throw(SystemError("a real one")))
    with pytest.raises(SystemError, match="a real one"):
        resim.resimulate_many(None, ["first"], [None], workers=1)


def test_a_signal_while_the_results_are_written_lets_them_be_written_whole_and_exits_130(tmp_path, monkeypatch,
                                                                                         capsys):
    """Issue 39, item 15: a Ctrl-C after the run's last step, while its results were written, gave exit 0 with no
    word.  The results are written whole (``ok``: the run did end), and the exit and one line say the signal came."""
    from fishfmu import cli
    from fishfmu.output import ownership
    from fishfmu.output.run_folder import RunFolder

    write_kpis = RunFolder.write_kpis

    def signalled_while_writing(self, doc):  # noqa: ANN001, ANN202
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, in the middle of the final write
        return write_kpis(self, doc)

    monkeypatch.setattr(RunFolder, "write_kpis", signalled_while_writing)
    out = tmp_path / "o"
    junit = tmp_path / "junit.xml"
    monkeypatch.setattr(sys, "argv", ["fishfmu", "run", SCENARIO, "--out", str(out), "--set", "run.duration_s=1",
                                      "--set", "fish.count=1", "--no-report", "--junit", str(junit)])
    with pytest.raises(SystemExit) as done:
        cli.main()
    assert done.value.code == 130
    err = capsys.readouterr().err
    assert "SIGINT after the run had ended" in err and "written whole" in err, err
    assert run_info(out)["status"] == "ok"
    assert json.loads((out / "kpis.json").read_text())["status"] == "ok"
    assert (out / "signals.csv").is_file() and (out / "run" / "dataset.toml").is_file() and junit.is_file()
    assert ownership.first_foreign(out) is None


def wait_for_text(path: Path, text: str, proc: subprocess.Popen, timeout_s: float = 180.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, path.read_text()
        if text in path.read_text():
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} not in {path} within {timeout_s} s")


def test_ctrl_c_to_a_benchmark_writes_what_it_measured_marked_partial(tmp_path):
    """Issue 39, item 12: an interrupted benchmark wrote nothing; it writes the cases it measured, marked."""
    results = tmp_path / "pile.json"
    proc, _ = launch(["bench", "pile", "--fish", "0,1,2,3,4,5,6,7,8", "--duration", "2", "--json", str(results)],
                     tmp_path)
    wait_for_text(tmp_path / "stderr.txt", "measured 1 fish", proc)
    rc, err = stop(proc, signal.SIGINT, True, tmp_path)
    assert rc == 130, err
    assert "Traceback" not in err and f"what it measured is in {results} (status: partial)" in err, err
    doc = json.loads(results.read_text())
    assert doc["status"] == "partial" and doc["stopped_by"] == "SIGINT"
    assert [r["fish"] for r in doc["records"]][:2] == [0, 1] and len(doc["records"]) < 9


def test_ctrl_c_to_bench_serve_is_one_line_no_traceback(tmp_path):
    """Raised inside asyncio's event loop (the PLC stand-in), the signal was caught and logged there with a
    traceback; now the stand-in only polls the stop request."""
    results = tmp_path / "serve.json"
    proc, _ = launch(["bench", "serve", "--set", "run.duration_s=30", "--json", str(results)], tmp_path)
    deadline = time.monotonic() + 120
    while not any("serve" in p.cmdline() for p in psutil.Process(proc.pid).children()):  # the served case runs
        assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "stderr.txt").read_text()
        time.sleep(0.2)
    time.sleep(4.0)  # the PLC stand-in connects and scans
    rc, err = stop(proc, signal.SIGINT, True, tmp_path)
    assert rc == 130, err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("stopped: by SIGINT"), err
    assert json.loads(results.read_text())["status"] == "partial"


# ------------------------------------------------------------------ the session itself, in-process

def test_session_owns_a_temporary_folder_and_gives_it_back(tmp_path, monkeypatch):
    import tempfile
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    tempfile.tempdir = None
    try:
        with session() as s:
            assert os.environ["TMPDIR"] == str(s.tmp) and s.tmp.parent == tmp_path
            (Path(tempfile.mkdtemp(prefix="fishfmu-fmu-")) / "x").write_text("unpacked")
        assert os.environ["TMPDIR"] == str(tmp_path) and list(tmp_path.iterdir()) == []
    finally:
        tempfile.tempdir = None


def test_a_signal_while_deferred_is_raised_at_the_end_of_the_block(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    reached = []
    with pytest.raises(Interrupted) as info:
        with session():
            with deferred_signals():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)
                reached.append("end of block")
    assert reached == ["end of block"] and info.value.exit_code == 143
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL or callable(signal.getsignal(signal.SIGTERM))
