"""Output files fishfmu owns, by its manifest only: one test per promise (docs/guarantees.md).

Every test checks that the user's files are byte-identical afterwards.  Commands that are refused
stop before simulating, so the subprocess calls are cheap; one real (0.5 s, one fish) run is made
once and copied where a test needs an earlier run.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from plant.errors import InputError

from fishfmu.output import manifest, ownership
from fishfmu.output.run_folder import prepare_out_dir
from fishfmu.output.atomic import write_json_atomic, write_text_atomic
from tests.test_measured import small_dataset  # noqa: F401 (a fixture, used by name)

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
QUICK = ["--no-report", "--set", "run.duration_s=0.5", "--set", "fish.count=1", "--set", "expect={}"]


def fishfmu(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "CI": "1"})


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (symbolic links as their target text) with its bytes."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            p = Path(dirpath) / name
            out[str(p.relative_to(root))] = os.readlink(p).encode() if p.is_symlink() else p.read_bytes()
    return out


@pytest.fixture(scope="module")
def earlier_run(tmp_path_factory) -> Path:
    """A folder holding a finished fishfmu run (made once by the command)."""
    base = tmp_path_factory.mktemp("earlier")
    proc = fishfmu("run", PAPER, "--out", base / "run", *QUICK, cwd=base)
    assert proc.returncode == 0, proc.stderr
    return base / "run"


def copy_run(earlier_run: Path, to: Path) -> Path:
    shutil.copytree(earlier_run, to, symlinks=True)
    return to


def test_a_user_file_next_to_a_fake_run_info_survives_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "run_info.json").write_text('{"status": "ok", "tool": "logger"}\n')  # another tool's marker
    (out / "notes.txt").write_text("my notes\n")
    before = snapshot(tmp_path)
    proc = fishfmu("run", PAPER, "--out", out, "--overwrite", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "notes.txt" in proc.stderr and "not written by fishfmu" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert snapshot(tmp_path) == before


def test_the_default_folder_needs_overwrite_and_never_takes_user_files(tmp_path: Path, earlier_run: Path) -> None:
    scen = tmp_path / "paper_dump.toml"
    shutil.copy(PAPER, scen)
    out = copy_run(earlier_run, tmp_path / "out" / "paper_dump")  # what `fishfmu run paper_dump.toml` made
    refused = fishfmu("run", scen, *QUICK, cwd=tmp_path)  # no --out: out/paper_dump
    assert refused.returncode == 2 and "pass --overwrite" in refused.stderr, refused.stderr
    (out / "notes.md").write_text("what I saw in this run\n")
    before = snapshot(tmp_path)
    for extra in ([], ["--overwrite"]):
        proc = fishfmu("run", scen, *QUICK, *extra, cwd=tmp_path)
        assert proc.returncode == 2 and "notes.md (not written by fishfmu)" in proc.stderr, proc.stderr
        assert snapshot(tmp_path) == before


def test_an_earlier_run_is_replaced_with_overwrite_and_refused_without(tmp_path: Path, earlier_run: Path) -> None:
    out = copy_run(earlier_run, tmp_path / "run")
    before = snapshot(tmp_path)
    refused = fishfmu("run", PAPER, "--out", out, *QUICK, cwd=tmp_path)
    assert refused.returncode == 2 and "holds an earlier run; pass --overwrite" in refused.stderr, refused.stderr
    assert snapshot(tmp_path) == before
    done = fishfmu("run", PAPER, "--out", out, "--overwrite", *QUICK, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "kpis.json").read_text())["status"] == "ok"
    assert ownership.first_foreign(out) is None


def test_a_file_of_ours_changed_by_the_user_makes_the_folder_foreign(tmp_path: Path, earlier_run: Path) -> None:
    out = copy_run(earlier_run, tmp_path / "run")
    (out / "run" / "runs" / "paper_dump" / "tracks.csv").write_text("t_s,fish_id,x_m\n0,a,1\n")  # edited by hand
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=r"run/runs/paper_dump/tracks.csv \(changed since fishfmu wrote it\)"):
        prepare_out_dir(out, overwrite=True)
    assert snapshot(tmp_path) == before


def test_a_symbolic_link_out_of_the_folder_is_foreign_and_its_target_untouched(tmp_path: Path,
                                                                                earlier_run: Path) -> None:
    out = copy_run(earlier_run, tmp_path / "run")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious.csv").write_text("1,2,3\n")
    (out / "data").symlink_to(elsewhere, target_is_directory=True)
    (out / "kpis_link.json").symlink_to(elsewhere / "precious.csv")
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=r"data \(a symbolic link"):
        prepare_out_dir(out, overwrite=True)
    proc = fishfmu("run", PAPER, "--out", out, "--overwrite", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2 and "symbolic link" in proc.stderr, proc.stderr
    assert snapshot(tmp_path) == before
    assert (elsewhere / "precious.csv").read_text() == "1,2,3\n"


def test_a_dataset_folder_is_never_the_compare_output(tmp_path: Path, small_dataset: Path) -> None:  # noqa: F811
    dataset = small_dataset
    assert dataset.parent == tmp_path
    (dataset / "run_info.json").write_text('{"status": "ok", "logger": "line 3"}\n')
    before = snapshot(tmp_path)
    for out in (dataset, dataset / "compare", tmp_path):
        proc = fishfmu("compare", dataset, "--out", out, "--overwrite", "--workers", "1", cwd=tmp_path)
        assert proc.returncode == 2, proc.stderr
        assert "input" in proc.stderr and str(dataset) in proc.stderr, proc.stderr
        assert snapshot(tmp_path) == before


def test_junit_never_writes_over_the_scenario(tmp_path: Path) -> None:
    scen = tmp_path / "s.toml"
    shutil.copy(PAPER, scen)
    before = snapshot(tmp_path)
    proc = fishfmu("run", scen, "--out", tmp_path / "out", "--junit", scen, *QUICK, cwd=tmp_path)
    assert proc.returncode == 2 and "is an input of this command" in proc.stderr, proc.stderr
    assert snapshot(tmp_path) == before


def test_single_file_outputs_replace_only_their_own_file(tmp_path: Path, earlier_run: Path) -> None:
    run = copy_run(earlier_run, tmp_path / "run")
    (tmp_path / "page.html").write_text("<p>someone's page</p>\n")
    before = snapshot(tmp_path)
    proc = fishfmu("replay", run, "--out", tmp_path / "page.html", cwd=tmp_path)
    assert proc.returncode == 2 and "page.html: exists and was not written by fishfmu" in proc.stderr, proc.stderr
    assert snapshot(tmp_path) == before
    with pytest.raises(InputError, match="is an input"):
        ownership.check_single_file_target(run / "poses.npz", [run / "poses.npz"])
    # a file fishfmu wrote (listed in its folder's manifest) may be written again; changed, it may not
    junit = tmp_path / "ci" / "junit.xml"
    ownership.check_single_file_target(junit)
    write_text_atomic(junit, "<testsuite/>\n")
    manifest.close_all()
    assert ownership.check_single_file_target(junit) == junit
    junit.write_text("<testsuite name='edited'/>\n")
    with pytest.raises(InputError, match="changed since fishfmu wrote it"):
        ownership.check_single_file_target(junit)


CRASH = """
import os, signal, sys
from fishfmu.output.run_folder import prepare_out_dir
from fishfmu.output.atomic import write_json_atomic, write_text_atomic
out = prepare_out_dir(sys.argv[1], overwrite=False, command="compare")
write_text_atomic(out / "kpis.csv", "run_id,x\\nr1,1\\n")
write_json_atomic(out / "sub" / "a.json", {"a": 1})
real_replace = os.replace
os.replace = lambda *a: os.kill(os.getpid(), signal.SIGKILL)  # killed in the middle of the next write
write_text_atomic(out / "report.html", "<html>")
"""


def test_a_killed_command_leaves_a_folder_that_overwrite_replaces(tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    proc = subprocess.run([sys.executable, "-c", CRASH, str(out)], cwd=tmp_path, capture_output=True)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    names = sorted(p.name for p in out.iterdir())
    assert manifest.JOURNAL in names and any(n.startswith(".report.html.") for n in names)  # the temp file
    assert json.loads((out / manifest.MANIFEST).read_text())["status"] == "writing"
    with pytest.raises(InputError, match=r"did not finish \(killed\?\); pass --overwrite"):
        prepare_out_dir(out, overwrite=False)
    (tmp_path / "keep.txt").write_text("next to it, not in it\n")
    prepare_out_dir(out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [manifest.MANIFEST]
    assert (tmp_path / "keep.txt").read_text() == "next to it, not in it\n"


CRASH_SWEEP = CRASH.replace("from fishfmu.output.run_folder import prepare_out_dir", "from fishfmu.output.ownership "
                             "import open_resumable").replace('prepare_out_dir(sys.argv[1], overwrite=False, '
                                                              'command="compare")', "open_resumable(sys.argv[1])")


def test_a_resumed_sweep_removes_the_temporary_files_a_killed_write_left(tmp_path: Path) -> None:
    """Issue 39, item 15: the ``.part`` files of a sweep stopped in the middle of a write stayed in its folder
    through every resume.  They are fishfmu's (recorded with size and hash): the resume removes them."""
    out = tmp_path / "sweep"
    proc = subprocess.run([sys.executable, "-c", CRASH_SWEEP, str(out)], cwd=tmp_path, capture_output=True)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    assert [p.name for p in out.iterdir() if p.name.endswith(".part")]  # .report.html.<random>.part
    assert ownership.open_resumable(out) == out
    manifest.close_all()
    assert not [p for p in out.rglob("*") if ".part" in p.name], sorted(p.name for p in out.rglob("*"))
    assert (out / "kpis.csv").read_text() == "run_id,x\nr1,1\n" and (out / "sub" / "a.json").is_file()  # kept
    listed = json.loads((out / manifest.MANIFEST).read_text())["files"]
    assert sorted(listed) == ["kpis.csv", "sub/a.json"]
    assert ownership.first_foreign(out) is None


def test_sweep_resumes_only_into_a_folder_of_its_own(tmp_path: Path) -> None:
    out = ownership.open_resumable(tmp_path / "sweep")
    write_json_atomic(out / "points" / "p1.json", {"run_id": "p1"})
    manifest.close_all()
    assert ownership.open_resumable(out) == out and (out / "points" / "p1.json").is_file()  # kept
    manifest.close_all()
    (out / "points" / "mine.json").write_text("{}")
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=r"points/mine.json \(not written by fishfmu\)"):
        ownership.open_resumable(out)
    assert snapshot(tmp_path) == before


def test_an_output_location_that_cannot_be_made_is_exit_2(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a folder\n")
    before = snapshot(tmp_path)
    proc = fishfmu("run", PAPER, "--out", tmp_path / "file" / "out", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [f"error: {tmp_path / 'file' / 'out'}: cannot create the output "
                                                "folder: Not a directory"]
    assert snapshot(tmp_path) == before


def test_a_full_disk_while_writing_is_one_line_not_an_internal_error(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import errno
    out = prepare_out_dir(tmp_path / "out", overwrite=False)

    def full(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(manifest.OutputError, match="kpis.json: cannot write: no space left on device"):
        write_json_atomic(out / "kpis.json", {"a": 1})
    assert not [p for p in out.iterdir() if p.name.endswith(".part")]
