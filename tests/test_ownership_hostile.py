"""The manifest and journal as a hostile or careless user leaves them, and files that must go through the
atomic path (docs/guarantees.md): nothing is fishfmu's without its size and hash, a manifest
or journal fishfmu cannot read strictly is exit 2 naming it with nothing touched, and a file rewritten
by fishfmu (a plot of a resumed sweep) is a new file: a hard link to the old one keeps what it held.

Most cases call the ownership checks in process (an InputError is exit 2 on the command line); a few
run the command to check the exit code and the one-line message.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from plant.errors import InputError

from fishfmu.output import manifest, ownership
from fishfmu.output.atomic import write_text_atomic
from fishfmu.output.manifest import JOURNAL, MANIFEST
from fishfmu.output.run_folder import prepare_out_dir
from tests.test_ownership import PAPER, QUICK, fishfmu

KPIS = b"run_id,x\nr1,1\n"
KPIS_SHA = hashlib.sha256(KPIS).hexdigest()


def snapshot(root: Path) -> dict[str, bytes | str]:
    """Every entry under ``root``: a file's bytes, a link's target, a folder or FIFO by its kind
    (a FIFO is never opened: that would block)."""
    out: dict[str, bytes | str] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in filenames + dirnames:
            p = Path(dirpath) / name
            mode = p.lstat().st_mode
            rel = str(p.relative_to(root))
            out[rel] = (f"-> {os.readlink(p)}" if stat.S_ISLNK(mode) else p.read_bytes() if stat.S_ISREG(mode)
                        else "folder" if stat.S_ISDIR(mode) else "FIFO" if stat.S_ISFIFO(mode) else "other")
    return out


def ours(out: Path) -> Path:
    """A folder fishfmu wrote (one file, ``kpis.csv``), its manifest closed."""
    prepare_out_dir(out, overwrite=False, command="compare")
    write_text_atomic(out / "kpis.csv", KPIS.decode())
    manifest.close_all()
    return out


# ---------------------------------------------------------------- plots go through the atomic path

def _figure(y: float):
    from matplotlib.figure import Figure
    fig = Figure(figsize=(2, 2), dpi=40)
    fig.add_subplot().plot([0, 1], [0, y])
    return fig


def _plot_with(writer: str, out: Path, y: float) -> Path:
    """Write one plot the way ``writer``'s module does; returns its path."""
    if writer == "sweep":
        from fishfmu.batch.sweep_report import write_plots
        summary = pd.DataFrame({"belt.speed_mps": [0.5, 1.0], "singulation_rate_mean": [0.5, y],
                                "singulation_rate_ci_low": [0.4, y - 0.1], "singulation_rate_ci_high": [0.6, y + 0.1]})
        write_plots(summary, ["belt.speed_mps"], out / "plots")
        return out / "plots" / "singulation_rate__belt_speed_mps.png"
    if writer == "compare":
        from fishfmu.analysis.compare_report import _save
        _save(_figure(y), out / "errors.png")
        return out / "errors.png"
    from fishfmu.analysis.diagnose_report import _img  # (bench's plot writes the same way; tests import no benchmark)
    _img(_figure(y), out / "evidence.png")
    return out / "evidence.png"


@pytest.mark.parametrize("writer", ["sweep", "compare", "diagnose"])
def test_a_plot_written_again_leaves_a_hard_link_to_the_earlier_one_alone(tmp_path: Path, writer: str) -> None:
    out = ownership.open_resumable(tmp_path / "out")  # a sweep resumes into its folder and plots again
    png = _plot_with(writer, out, 0.7)
    first = png.read_bytes()
    os.link(png, tmp_path / "backup.png")  # the user's (or a backup tool's) hard link
    _plot_with(writer, out, 0.9)
    assert png.read_bytes() != first
    assert (tmp_path / "backup.png").read_bytes() == first
    manifest.close_all()
    assert ownership.first_foreign(out) is None  # the new plot is recorded with its size and hash
    assert not [p for p in out.rglob("*.part")]


# ---------------------------------------------------------------- nothing is ours without its size and hash

@pytest.mark.parametrize("victim, foreign", [("notes.txt", "notes.txt"), ("thesis", "thesis/chapter1.tex")])
@pytest.mark.parametrize("where", ["journal", "manifest"])
def test_a_temporary_name_without_size_and_hash_makes_nothing_ours(tmp_path: Path, where: str, victim: str,
                                                                   foreign: str) -> None:
    out = ours(tmp_path / "out")
    (out / "thesis").mkdir()
    (out / foreign).write_text("the user's own\n")
    if where == "journal":
        (out / JOURNAL).write_text(json.dumps({"t": victim}) + "\n")  # one edited line
    else:
        doc = json.loads((out / MANIFEST).read_text())
        (out / MANIFEST).write_text(json.dumps({**doc, "temps": [victim]}))
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=re.escape(f"{foreign} (not written by fishfmu)")):
        prepare_out_dir(out, overwrite=True)
    assert snapshot(tmp_path) == before


def test_overwrite_through_the_command_keeps_a_file_a_journal_line_names(tmp_path: Path) -> None:
    out = ours(tmp_path / "out")
    (out / "notes.txt").write_text("my notes\n")
    (out / JOURNAL).write_text('{"t": "notes.txt"}\n')
    before = snapshot(tmp_path)
    proc = fishfmu("run", PAPER, "--out", out, "--overwrite", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "notes.txt (not written by fishfmu)" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert snapshot(tmp_path) == before


def test_a_user_file_named_like_the_manifests_temporary_file_is_not_ours(tmp_path: Path) -> None:
    out = ours(tmp_path / "out")
    (out / f".{MANIFEST}.draft.part").write_text("the user's draft\n")  # as fishfmu names the manifest's
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=re.escape(f".{MANIFEST}.draft.part (a temporary name, but not a file")):
        prepare_out_dir(out, overwrite=True)
    assert snapshot(tmp_path) == before


KILL_MIDWAY = """
import os, signal, sys
from fishfmu.output.run_folder import prepare_out_dir
from fishfmu.output.atomic import write_text_atomic
out = prepare_out_dir(sys.argv[1], overwrite=False, command="compare")
write_text_atomic(out / "kpis.csv", "run_id,x\\nr1,1\\n")
real_fsync = os.fsync
def fsync(fd):  # killed while the temporary file is written, before it is complete on disk
    if os.readlink(f"/proc/self/fd/{fd}").endswith(".part"):
        os.kill(os.getpid(), signal.SIGKILL)
    real_fsync(fd)
os.fsync = fsync
write_text_atomic(out / "report.html", "<html>" * 1000)
"""


def test_a_temporary_file_a_kill_cut_short_is_not_ours(tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    proc = subprocess.run([sys.executable, "-c", KILL_MIDWAY, str(out)], cwd=tmp_path, capture_output=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    [tmp] = [p for p in out.iterdir() if p.name.startswith(".report.html.")]
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match=re.escape(f"{tmp.name} (a temporary name, but not a file fishfmu recorded")):
        prepare_out_dir(out, overwrite=True)
    assert snapshot(tmp_path) == before
    tmp.unlink()  # what the message asks; then the folder is fishfmu's again
    prepare_out_dir(out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST]


def test_a_folder_is_removed_only_when_fishfmu_made_it_and_it_is_empty(tmp_path: Path) -> None:
    out = ours(tmp_path / "out")
    (out / "mine").mkdir()  # empty, made by the user
    (out / "thesis").mkdir()
    (out / "thesis" / "chapter1.tex").write_text("the user's own\n")
    (out / JOURNAL).write_text('{"d": "thesis"}\n{"d": "mine"}\n')  # claimed, but thesis holds a user file
    with pytest.raises(InputError, match=re.escape("thesis/chapter1.tex (not written by fishfmu)")):
        prepare_out_dir(out, overwrite=True)
    (out / "thesis" / "chapter1.tex").unlink()
    (out / JOURNAL).write_text('{"d": "thesis"}\n')
    prepare_out_dir(out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "mine"]  # the folder fishfmu did not make stays


# ---------------------------------------------------------------- malformed manifests and journals: exit 2

def _entry(**changes) -> bytes:
    return (json.dumps({"f": "kpis.csv", "size": len(KPIS), "sha256": KPIS_SHA, **changes}) + "\n").encode()


JOURNALS = {
    "a number": (b"5\n", "line 1"),
    "null": (b'{"d": "sub"}\nnull\n', "line 2"),
    "a size that is text": (_entry(size="abc"), "line 1"),
    "a size of 1e400": (_entry(size=1e400), "line 1"),
    "a negative size": (_entry(size=-1), "line 1"),
    "a size that is true": (_entry(size=True), "line 1"),
    "a hash that is not hex": (_entry(sha256="not-a-hash"), "line 1"),
    "a path out of the folder": (_entry(f="../elsewhere.csv"), "line 1"),
    "an absolute path": (_entry(f="/etc/passwd"), "line 1"),
    "an unknown entry": (_entry(mode=644), "line 1"),
    "invalid UTF-8": (b'{"d": "\xff\xfe"}\n', "not UTF-8"),
    "100 000-deep JSON": (b"[" * 100_000 + b"]" * 100_000 + b"\n", "line 1"),
    "a torn line that is not the last": (b'{"f": "kpis.c\n{"d": "sub"}\n', "line 1"),
}


@pytest.mark.parametrize("case", JOURNALS)
def test_a_malformed_journal_is_bad_input_naming_it(tmp_path: Path, case: str) -> None:
    out = ours(tmp_path / "out")
    text, where = JOURNALS[case]
    (out / JOURNAL).write_bytes(text)
    before = snapshot(tmp_path)
    for attempt in (lambda: prepare_out_dir(out, overwrite=True), lambda: ownership.open_resumable(out),
                    lambda: ownership.check_single_file_target(out / "junit.xml")):
        with pytest.raises(InputError) as err:
            attempt()
        message = str(err.value)
        assert message.startswith(f"{out / JOURNAL}: ") and where in message and "\n" not in message, message
        assert snapshot(tmp_path) == before


def _manifest(**changes) -> bytes:
    doc = {"fishfmu_manifest": 1, "status": "closed", "command": "compare",
           "files": {"kpis.csv": [[len(KPIS), KPIS_SHA]]}, "dirs": []}
    return json.dumps({**doc, **changes}).encode()


MANIFESTS = {
    "a number": b"5",
    "null": b"null",
    "not JSON": b"{",
    "another tool's file": b'{"tool": "logger"}',
    "a size that is text": _manifest(files={"kpis.csv": [["abc", KPIS_SHA]]}),
    "a size of 1e400": _manifest(files={"kpis.csv": [[1e400, KPIS_SHA]]}),
    "a hash that is not hex": _manifest(files={"kpis.csv": [[len(KPIS), "xyz"]]}),
    "a path out of the folder": _manifest(files={"../../x.csv": [[1, KPIS_SHA]]}),
    "a folder out of the folder": _manifest(dirs=[".."]),
    "temporary names that are not paths": _manifest(temps=[5]),
    "invalid UTF-8": b'{"fishfmu_manifest": 1, "status": "\xff"}',
    "100 000-deep JSON": b"[" * 100_000 + b"]" * 100_000,
}


@pytest.mark.parametrize("case", MANIFESTS)
def test_a_malformed_manifest_is_bad_input_naming_it(tmp_path: Path, case: str) -> None:
    out = ours(tmp_path / "out")
    (out / MANIFEST).write_bytes(MANIFESTS[case])
    before = snapshot(tmp_path)
    with pytest.raises(InputError) as err:
        prepare_out_dir(out, overwrite=True)
    message = str(err.value)
    assert message.startswith(f"{out / MANIFEST}: ") and "nothing was touched" in message and "\n" not in message
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("name", [MANIFEST, JOURNAL])
@pytest.mark.parametrize("kind", ["folder", "symbolic link", "FIFO"])
def test_a_manifest_or_journal_that_is_not_a_regular_file_is_bad_input(tmp_path: Path, name: str, kind: str) -> None:
    out = ours(tmp_path / "out")
    (out / name).unlink(missing_ok=True)
    if kind == "folder":
        (out / name).mkdir()
        (out / name / "inside.txt").write_text("the user's\n")
    elif kind == "symbolic link":
        (tmp_path / "elsewhere.json").write_bytes(_manifest() if name == MANIFEST else _entry())
        (out / name).symlink_to(tmp_path / "elsewhere.json")
    else:
        os.mkfifo(out / name)  # reading it would block: it must not be opened that way
    before = snapshot(tmp_path)
    for attempt in (lambda: prepare_out_dir(out, overwrite=True), lambda: ownership.open_resumable(out)):
        with pytest.raises(InputError, match=re.escape(f"{out / name}: ")):
            attempt()
        assert snapshot(tmp_path) == before
        assert (out / name).exists() or (out / name).is_symlink()


@pytest.mark.parametrize("case", ["null journal line", "journal is a folder", "deep manifest"])
def test_the_command_exits_2_in_one_line_on_a_folder_it_cannot_vouch_for(tmp_path: Path, case: str) -> None:
    out = ours(tmp_path / "out")
    if case == "null journal line":
        bad = out / JOURNAL
        bad.write_text("null\n")
    elif case == "journal is a folder":
        bad = out / JOURNAL
        bad.mkdir()
    else:
        bad = out / MANIFEST
        bad.write_bytes(MANIFESTS["100 000-deep JSON"])
    before = snapshot(tmp_path)
    proc = fishfmu("run", PAPER, "--out", out, "--overwrite", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"error: {bad}: ") and "nothing was touched" in line, line
    assert snapshot(tmp_path) == before


def test_a_journal_torn_by_a_kill_is_read_and_appended_to(tmp_path: Path) -> None:
    out = ours(tmp_path / "out")
    (out / JOURNAL).write_bytes(_entry() + b'{"f": "report.ht')  # the last line, cut by a kill
    assert ownership.first_foreign(out) is None
    target = ownership.check_single_file_target(out / "junit.xml")  # appends to the journal
    write_text_atomic(target, "<testsuite/>\n")
    manifest.close_all()
    assert sorted(json.loads((out / MANIFEST).read_text())["files"]) == ["junit.xml", "kpis.csv"]
    assert not (out / JOURNAL).exists() and ownership.first_foreign(out) is None


KILL_IN_MANIFEST = """
import os, signal, sys
from fishfmu.output import manifest
from fishfmu.output.run_folder import prepare_out_dir
from fishfmu.output.atomic import write_text_atomic
out = prepare_out_dir(sys.argv[1], overwrite=False, command="compare")
write_text_atomic(out / "kpis.csv", "run_id,x\\nr1,1\\n")
real_replace = os.replace
def replace(src, dst):  # killed as the manifest is renamed into place at the end of the command
    if str(dst).endswith(manifest.MANIFEST) and "kpis.csv" in open(src).read():
        os.kill(os.getpid(), signal.SIGKILL)
    real_replace(src, dst)
os.replace = replace
manifest.close_all()
"""


def test_the_manifests_own_temporary_file_is_recorded_with_its_hash(tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    proc = subprocess.run([sys.executable, "-c", KILL_IN_MANIFEST, str(out)], cwd=tmp_path, capture_output=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    [tmp] = [p for p in out.iterdir() if p.name.startswith(f".{MANIFEST}.")]
    assert tmp.name in (out / JOURNAL).read_text()  # its size and hash, journaled before the rename
    prepare_out_dir(out, overwrite=True)
    manifest.close_all()
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST]
