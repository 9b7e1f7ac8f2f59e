"""Which files in an output location are fishfmu's: the manifest, and the rules built on it.

Every folder fishfmu writes into holds ``.fishfmu-manifest.json``: each file fishfmu wrote there
(path relative to the folder) with its size and SHA-256, the folders it made, and the temporary
names it was writing under.  While a command writes, each write is first appended to
``.fishfmu-manifest.journal`` (one JSON line, flushed to disk *before* the file appears under its
name), and the journal is folded into the manifest when the command ends; so a command killed
outright (``kill -9``) still leaves a folder whose every file is accounted for.

The rules (nothing else proves ownership; a ``run_info.json`` is just a file):

* An output folder that exists and is not empty is accepted only if every entry in it is ours:
  a file listed in the manifest with the same size and hash (a file of ours that was changed is no
  longer ours), a temporary name we recorded, or a folder whose entries are all ours.  A symbolic
  link is never ours (fishfmu writes none) and is never followed.  Otherwise the command stops
  with exit 2 naming the first foreign file, and nothing is touched.
* A folder of ours that holds an earlier result is replaced only with ``--overwrite`` (the default
  folder too): exactly the files in the manifest are removed, then the folders fishfmu made if
  they are empty; never a whole tree.  A command that crashed or was killed left only files of
  ours, so its folder is replaceable the same way.
* ``sweep`` resumes into a folder of ours and keeps what is there (:func:`open_resumable`).
* An output folder must not be, hold, or lie inside an input (scenario, FMU, dataset).
* A single-file output (``--junit``, ``replay --out``, ``bench --json/--plot``, a built ``.fmu``)
  may replace an existing file only if the manifest of the file's folder lists it unchanged,
  and never one of the command's inputs; the file is then recorded there (the folder gets a
  manifest listing just that file if it had none).

API: :func:`prepare_out_dir`, :func:`open_resumable`, :func:`check_single_file_target`,
:func:`record_written` (plus :func:`note_pending` / :func:`note_temp` / :func:`replace_into`, used by
the writers), :func:`first_foreign`.
"""

from __future__ import annotations

import atexit
import errno
import hashlib
import json
import os
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from plant.errors import InputError

MANIFEST = ".fishfmu-manifest.json"
JOURNAL = ".fishfmu-manifest.journal"
FORMAT = 1


@dataclass
class OutputError(InputError):
    """An output location that cannot be written (not a folder, read-only, disk full): exit 2."""


def os_error(exc: OSError, path: str | Path, doing: str = "cannot write") -> OutputError:
    """One line naming the path and the OS error."""
    why = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        why = "no space left on device"
    return OutputError(f"{doing}: {why}", file=path)


# ---------------------------------------------------------------- the manifest on disk

@dataclass
class State:
    """What a folder's manifest (and journal) say."""

    present: bool = False
    status: str | None = None
    command: str | None = None
    files: dict[str, list[list]] = field(default_factory=dict)
    """relative path -> accepted [size, sha256] versions (the newest last)"""
    temps: set[str] = field(default_factory=set)
    """temporary names (a file or a folder) fishfmu wrote under; ours whatever they hold"""
    dirs: set[str] = field(default_factory=set)

    def add_file(self, rel: str, size: int, sha: str) -> None:
        versions = self.files.setdefault(rel, [])
        if [size, sha] in versions:
            versions.remove([size, sha])
        versions.append([size, sha])

    def is_temp(self, rel: str) -> bool:
        parts = rel.split("/")
        return any("/".join(parts[:i]) in self.temps for i in range(1, len(parts) + 1))


def is_internal(name: str) -> bool:
    """The manifest, its journal, and a temporary name of the manifest (a write killed midway)."""
    return name in (MANIFEST, JOURNAL) or (name.startswith(f".{MANIFEST}.") and name.endswith(".part"))


def load_state(folder: Path) -> State:
    state = State()
    m = folder / MANIFEST
    if m.is_file() and not m.is_symlink():
        try:
            doc = json.loads(m.read_text(encoding="utf-8"))
            if doc.get("fishfmu_manifest") == FORMAT:
                state.present = True
                state.status, state.command = doc.get("status"), doc.get("command")
                for rel, versions in doc.get("files", {}).items():
                    for size, sha in versions:
                        state.add_file(rel, int(size), str(sha))
                state.temps = set(doc.get("temps", []))
                state.dirs = set(doc.get("dirs", []))
        except (OSError, ValueError, TypeError, AttributeError):
            state = State()
    j = folder / JOURNAL
    if j.is_file() and not j.is_symlink():
        state.present = True  # a command that wrote here was killed before folding its journal in
        try:
            lines = j.read_text(encoding="utf-8").splitlines()
        except OSError:
            lines = []
        for line in lines:
            try:
                op = json.loads(line)
            except ValueError:
                continue  # a line torn by a kill: what it announced was not written yet
            if "f" in op:
                state.add_file(op["f"], int(op["size"]), op["sha256"])
            elif "t" in op:
                state.temps.add(op["t"])
            elif "d" in op:
                state.dirs.add(op["d"])
    return state


def _write_manifest(folder: Path, state: State) -> None:
    head = {"fishfmu_manifest": FORMAT, "status": state.status, "command": state.command}
    lines = [f" {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    lines.append(' "files": {' + ",".join(f"\n  {json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(state.files.items()))
                 + "\n },")
    lines.append(f' "temps": {json.dumps(sorted(state.temps))},')
    lines.append(f' "dirs": {json.dumps(sorted(state.dirs))}')
    write_bytes_atomic(folder / MANIFEST, ("{\n" + "\n".join(lines) + "\n}\n").encode())


def _sha256_file(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
    return size, h.hexdigest()


# ---------------------------------------------------------------- ownership of a folder

@dataclass
class Scan:
    foreign: str | None = None
    """the first entry that is not ours, with why ('notes.txt (not written by fishfmu)')"""
    files: list[str] = field(default_factory=list)
    """our files, temporary ones included (relative paths)"""
    dirs: list[str] = field(default_factory=list)


def scan(folder: Path, state: State | None = None) -> Scan:
    """Walk ``folder`` (never following a symbolic link) and check every entry against its manifest."""
    state = load_state(folder) if state is None else state
    result = Scan()

    def walk(d: Path, prefix: str) -> bool:
        with os.scandir(d) as it:
            entries = sorted(it, key=lambda e: e.name)
        for e in entries:
            rel = prefix + e.name
            if not prefix and is_internal(e.name) and e.is_file(follow_symlinks=False):
                continue
            if e.is_symlink():
                result.foreign = f"{rel} (a symbolic link; fishfmu writes none)"
                return False
            if e.is_dir(follow_symlinks=False):
                if not walk(Path(e.path), rel + "/"):
                    return False
                result.dirs.append(rel)
                continue
            if not e.is_file(follow_symlinks=False):
                result.foreign = f"{rel} (not a regular file)"
                return False
            if state.is_temp(rel):
                result.files.append(rel)
                continue
            if rel not in state.files:
                result.foreign = f"{rel} (not written by fishfmu)"
                return False
            if [*_sha256_file(Path(e.path))] not in state.files[rel]:
                result.foreign = f"{rel} (changed since fishfmu wrote it)"
                return False
            result.files.append(rel)
        return True

    if not state.present:
        # nothing is ours: name the first entry (a manifest-less folder is someone else's)
        names = sorted(n for n in os.listdir(folder) if not is_internal(n))
        if names:
            result.foreign = f"{names[0]} (not written by fishfmu: the folder has no fishfmu manifest)"
        return result
    walk(folder, "")
    return result


def first_foreign(folder: str | Path) -> str | None:
    """The first entry of ``folder`` that fishfmu did not write (or that changed since), else None."""
    return scan(Path(folder)).foreign


def _refuse_foreign(out: Path, foreign: str) -> InputError:
    return InputError(f"output folder holds {foreign}; nothing was touched; choose another --out, or move "
                      f"what is not fishfmu's out of it", file=out)


def _remove_ours(out: Path, found: Scan, state: State) -> None:
    """Remove exactly our files, then the folders we made once empty, then the manifest."""
    for rel in found.files:
        (out / rel).unlink(missing_ok=True)
    for rel in sorted(found.dirs, key=lambda r: -r.count("/")):
        if rel in state.dirs or state.is_temp(rel):
            try:
                (out / rel).rmdir()
            except OSError:
                pass  # not empty (an empty folder we did not make is left)
    for name in os.listdir(out):
        if is_internal(name):
            (out / name).unlink(missing_ok=True)


# ---------------------------------------------------------------- sessions: who records writes

@dataclass
class _Session:
    root: Path
    only: set[str] | None = None
    """None: the whole folder is this command's output; else just these file names in it"""
    command: str | None = None
    journal_fh: object | None = None


_SESSIONS: dict[Path, _Session] = {}
_LOCK = threading.RLock()
_ATEXIT = False


def _abs(path: str | Path) -> Path:
    p = Path(path)
    return p.parent.resolve() / p.name if p.name else p.resolve()


def _open_session(root: Path, only: str | None = None, command: str | None = None) -> _Session:
    global _ATEXIT
    with _LOCK:
        if not _ATEXIT:
            atexit.register(close_all)
            _ATEXIT = True
        s = _SESSIONS.get(root)
        if s is None or only is None:
            if s is not None:
                _close(s)
            s = _SESSIONS[root] = _Session(root, None if only is None else set(), command)
        if only is not None and s.only is not None:
            s.only.add(only)
        return s


def _find(path: Path) -> tuple[_Session, str] | None:
    if not _SESSIONS:
        return None
    p = _abs(path)
    for root in sorted(_SESSIONS, key=lambda r: -len(r.parts)):
        s = _SESSIONS[root]
        if p == root or not p.is_relative_to(root):
            continue
        rel = p.relative_to(root).as_posix()
        if s.only is None or rel in s.only or any(rel.startswith(f".{n}.") for n in s.only):
            return s, rel
    return None


def _journal(s: _Session, ops: list[dict]) -> None:
    with _LOCK:
        if s.journal_fh is None:
            s.journal_fh = open(s.root / JOURNAL, "a", encoding="utf-8")
        s.journal_fh.write("".join(json.dumps(op) + "\n" for op in ops))
        s.journal_fh.flush()
        os.fsync(s.journal_fh.fileno())


def _dir_ops(rel: str) -> list[dict]:
    parts = rel.split("/")[:-1]
    return [{"d": "/".join(parts[:i])} for i in range(1, len(parts) + 1)]


def note_pending(tmp: str | Path | None, final: str | Path, data: bytes | None = None) -> None:
    """Record, before it appears, that ``final`` is ours (its bytes ``data``, or the file ``tmp``
    holds now) and that ``tmp`` is our temporary name.  Called by the atomic writers."""
    found = _find(Path(final))
    if found is None:
        return
    s, rel = found
    if rel in (MANIFEST, JOURNAL):
        return
    ops = _dir_ops(rel)
    if tmp is not None and _abs(tmp) != _abs(final):
        t = _find(Path(tmp))
        if t is not None and t[0] is s:
            ops.append({"t": t[1]})
    if data is not None:
        ops.append({"f": rel, "size": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    elif tmp is not None and Path(tmp).is_file():
        size, sha = _sha256_file(Path(tmp))
        ops.append({"f": rel, "size": size, "sha256": sha})
    _journal(s, ops)


# ---------------------------------------------------------------- the atomic writer

def _file_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


_FILE_MODE = _file_mode()


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write under a temporary name, record it in the folder's manifest, rename into place.
    An OS error (read-only, disk full, not a folder) is an :class:`OutputError`."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    except OSError as exc:
        raise os_error(exc, path) from None
    try:
        note_pending(tmp, path, data)
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), _FILE_MODE)  # mkstemp makes 0600; an output is as readable as any file
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            Path(tmp).unlink(missing_ok=True)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise os_error(exc, path) from None
        raise


def note_temp(path: str | Path) -> None:
    """Record ``path`` (a file or folder about to be written) as a temporary name of ours."""
    found = _find(Path(path))
    if found is not None:
        _journal(found[0], [*_dir_ops(found[1]), {"t": found[1]}])


def note_dir(path: str | Path) -> None:
    """Record a folder this command made (kept even while empty)."""
    found = _find(Path(path) / "x")
    if found is not None:
        _journal(found[0], _dir_ops(found[1]))


def replace_into(tmp: str | Path, final: str | Path) -> None:
    """``os.replace(tmp, final)`` for a file written by another library: recorded before the rename."""
    note_pending(tmp, final)
    os.replace(tmp, final)


def record_written(paths: Iterable[str | Path] | str | Path) -> None:
    """Record files (or every file under folders) that this command has just written."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    for p in map(Path, paths):
        if p.is_symlink():
            continue
        if p.is_dir():
            found = _find(p / "x")
            if found is not None:
                _journal(found[0], _dir_ops(found[1]))
            for sub in sorted(p.iterdir()):
                record_written(sub)
        elif p.is_file():
            note_pending(p, p)


def record_tree_as(src: Path, final: Path) -> None:
    """Before ``os.replace(src, final)`` of a folder: record each file under ``final``'s name."""
    found = _find(final / "x")
    if found is None:
        return
    ops = _dir_ops(found[1])
    for dirpath, dirnames, filenames in os.walk(src):
        rel_dir = Path(dirpath).relative_to(src)
        for d in dirnames:
            fr = _find(final / rel_dir / d / "x")
            if fr is not None:
                ops += _dir_ops(fr[1])
        for f in filenames:
            fr = _find(final / rel_dir / f)
            if fr is not None:
                size, sha = _sha256_file(Path(dirpath) / f)
                ops.append({"f": fr[1], "size": size, "sha256": sha})
    _journal(found[0], ops)


def _close(s: _Session, status: str | None = "closed") -> None:
    """Fold the journal into the manifest (files gone are dropped), then remove the journal."""
    with _LOCK:
        if s.journal_fh is not None:
            s.journal_fh.close()
            s.journal_fh = None
        _SESSIONS.pop(s.root, None)
        if not s.root.is_dir() or (s.only is not None and not (s.root / JOURNAL).exists()):
            return
        state = load_state(s.root)
        if not state.present:
            return
        if s.only is None:
            state.status, state.command = status, s.command or state.command
        elif state.status is None:
            state.status = "closed"
        state.files = {k: _current(s.root / k, v) for k, v in state.files.items() if (s.root / k).is_file()}
        state.temps = {t for t in state.temps if (s.root / t).exists()}
        state.dirs = {d for d in state.dirs if (s.root / d).is_dir()}
        _write_manifest(s.root, state)
        (s.root / JOURNAL).unlink(missing_ok=True)


def _current(path: Path, versions: list[list]) -> list[list]:
    """Of the versions written to ``path``, the one it holds now (all of them if none matches)."""
    if len(versions) < 2:
        return versions
    now = [*_sha256_file(path)]
    return [now] if now in versions else versions


def close(out: str | Path) -> None:
    """End the recording of ``out`` (the command is done with it): the manifest says ``closed``."""
    s = _SESSIONS.get(_abs(out))
    if s is not None:
        _close(s)


def close_all() -> None:
    for s in list(_SESSIONS.values()):
        try:
            _close(s)
        except OSError:
            pass  # the journal stays: it still says what is ours


def forget(out: str | Path) -> None:
    """Stop recording ``out`` without touching it (it is about to be removed)."""
    with _LOCK:
        s = _SESSIONS.pop(_abs(out), None)
        if s is not None and s.journal_fh is not None:
            s.journal_fh.close()


# ---------------------------------------------------------------- inputs

def _within(inner: Path, outer: Path) -> bool:
    return inner == outer or inner.is_relative_to(outer)


def check_not_input(out: Path, inputs: Iterable[str | Path | None], what: str = "output folder") -> None:
    """Refuse an output folder that is, holds, or lies inside an input."""
    o = Path(out).resolve()
    for inp in inputs:
        if inp is None:
            continue
        i = Path(inp).resolve()
        if _within(i, o):
            raise InputError(f"{what} would hold the input {inp}; choose an --out that does not contain it", file=out)
        if Path(inp).is_dir() and _within(o, i):
            raise InputError(f"{what} lies inside the input folder {inp}; choose an --out outside it", file=out)


def _create(out: Path) -> bool:
    """Make ``out`` if it is not there; True if this call made it."""
    existed = out.is_dir()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError("cannot create the output folder: a file is in the way", file=out) from None
    except OSError as exc:
        raise os_error(exc, out, "cannot create the output folder") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError("cannot write into the output folder: permission denied", file=out)
    return not existed


def _start(out: Path, command: str | None, keep: State | None = None, created: bool = False) -> None:
    """Mark ``out`` as ours from now on (manifest with status ``writing``) and record its writes."""
    root = _abs(out)
    for r in [r for r in _SESSIONS if _within(r, root)]:
        _close(_SESSIONS[r])
    state = keep if keep is not None else State()
    state.present, state.status, state.command = True, "writing", command
    try:
        _write_manifest(out, state)
        (out / JOURNAL).unlink(missing_ok=True)  # folded into the manifest just written
    except OutputError:
        if created and not any(out.iterdir()):  # a folder of the user's stays, even empty
            out.rmdir()
        raise
    _open_session(root, None, command)


# ---------------------------------------------------------------- the API for commands

def prepare_out_dir(out: str | Path, overwrite: bool, inputs: Iterable[str | Path | None] = (),
                    command: str | None = None) -> Path:
    """Create the output folder ``out`` for a new result, or accept one of ours (replacing its earlier
    result only when ``overwrite``); refuse a folder with anything fishfmu did not write, and one
    that is, holds or lies inside an input.  Records this command's writes into ``out``'s manifest."""
    out = Path(out)
    check_not_input(out, inputs)
    if out.is_symlink() and not out.exists():
        raise OutputError("is a symbolic link to nowhere", file=out)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=out)
    if not out.exists():
        _start(out, command, created=_create(out))
        return out
    try:
        entries = [n for n in os.listdir(out)]
    except OSError as exc:
        raise os_error(exc, out, "cannot read the output folder") from None
    if entries:
        state = load_state(out)
        found = scan(out, state)
        if found.foreign:
            raise _refuse_foreign(out, found.foreign)
        if found.files or [n for n in entries if not is_internal(n)]:
            if not overwrite:
                raise InputError(f"output folder holds {_describe(out, state)}; pass --overwrite to replace it",
                                 file=out)
            forget(out)
            try:
                _remove_ours(out, found, state)
            except OSError as exc:
                raise os_error(exc, out, "cannot remove the earlier result") from None
    _start(out, command, created=_create(out))
    return out


def _describe(out: Path, state: State) -> str:
    unfinished = state.status == "writing"
    try:
        info = json.loads((out / "run_info.json").read_text())
        unfinished = unfinished or info.get("status") == "running"
    except (OSError, ValueError, AttributeError):
        pass
    return "an earlier run that did not finish (killed?)" if unfinished else "an earlier run"


def open_resumable(out: str | Path, inputs: Iterable[str | Path | None] = (), command: str | None = "sweep") -> Path:
    """An output folder that a later call continues (``sweep``): created, or accepted when it holds
    only files of ours (kept); anything foreign is refused.  Inside a folder this command is already
    writing (``run --seeds``'s ``seeds/``) it is simply made."""
    out = Path(out)
    check_not_input(out, inputs)
    found = _find(out / "x")
    if found is not None and found[0].only is None:
        if out.exists() and not out.is_dir():
            raise InputError("exists and is not a folder", file=out)
        _create(out)
        _journal(found[0], _dir_ops(found[1]))
        return out
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=out)
    if not out.exists():
        _start(out, command, created=_create(out))
        return out
    state = load_state(out)
    if [n for n in os.listdir(out) if not is_internal(n)]:
        found_scan = scan(out, state)
        if found_scan.foreign:
            raise _refuse_foreign(out, found_scan.foreign)
    _start(out, command, keep=state if state.present else None, created=_create(out))
    return out


def check_single_file_target(path: str | Path, inputs: Iterable[str | Path | None] = ()) -> Path:
    """Accept ``path`` as a single-file output: not an input, not inside an input folder, and, if it
    exists, a file of ours (listed unchanged in its folder's manifest).  Its write is then recorded
    in that folder's manifest."""
    path = Path(path)
    for inp in inputs:
        if inp is None:
            continue
        i = Path(inp)
        same = path.exists() and i.exists() and os.path.samefile(path, i)
        if same or _abs(path) == i.resolve():
            raise InputError(f"is an input of this command ({inp}); refusing to write over it", file=path)
        if i.is_dir() and _within(_abs(path), i.resolve()):
            raise InputError(f"lies inside the input folder {inp}; refusing to write there", file=path)
    if path.is_symlink():
        raise InputError("is a symbolic link, not written by fishfmu; refusing to write over it", file=path)
    if path.exists():
        if not path.is_file():
            raise InputError("exists and is not a file", file=path)
        state = load_state(path.parent)
        if path.name not in state.files or [*_sha256_file(path)] not in state.files[path.name]:
            why = "was changed since fishfmu wrote it" if path.name in state.files else "was not written by fishfmu"
            raise InputError(f"exists and {why}; refusing to write over it (remove it, or choose another file)",
                             file=path)
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"cannot write here: {parent} is not a folder", file=path)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError("cannot write here: permission denied", file=path)
    _open_session(_abs(path).parent, only=path.name)
    return path
