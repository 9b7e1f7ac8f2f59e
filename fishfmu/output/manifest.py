"""What fishfmu wrote: the manifest of a folder, the journal of a command's writes, the atomic writer.

Every folder fishfmu writes into holds ``.fishfmu-manifest.json``: each file fishfmu wrote there
(path relative to the folder) with its size and SHA-256, the folders it made, and the temporary
names it was writing under.  While a command writes, each write is first appended to
``.fishfmu-manifest.journal`` (one JSON line, flushed to disk *before* the file appears under its
name), and the journal is folded into the manifest when the command ends; so a command killed
outright (``kill -9``) still leaves a folder whose every file is accounted for.

A session records one command's writes into a whole folder (:func:`start_session`) or into some
single-file outputs of it (:func:`open_session`).  Which files are fishfmu's, and so may be written
over or removed, is decided from the manifest by :mod:`fishfmu.output.ownership`.

API: :func:`write_bytes_atomic`, :func:`record_written`, the writers' hooks (:func:`note_pending`,
:func:`note_temp`, :func:`replace_into`, ...), :func:`load_state`, :func:`close_all`.
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


def sha256_file(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
    return size, h.hexdigest()


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


def abs_path(path: str | Path) -> Path:
    """``path`` made absolute with its folder resolved (the name itself, perhaps a link, is kept)."""
    p = Path(path)
    return p.parent.resolve() / p.name if p.name else p.resolve()


def open_session(root: Path, only: str | None = None, command: str | None = None) -> _Session:
    """Record this command's writes into the folder ``root`` (absolute): all of them (``only`` None),
    or just those of the file named ``only`` (added to the names a single-file session records)."""
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
    p = abs_path(path)
    for root in sorted(_SESSIONS, key=lambda r: -len(r.parts)):
        s = _SESSIONS[root]
        if p == root or not p.is_relative_to(root):
            continue
        rel = p.relative_to(root).as_posix()
        if s.only is None or rel in s.only or any(rel.startswith(f".{n}.") for n in s.only):
            return s, rel
    return None


def inside_folder_being_written(path: str | Path) -> bool:
    """Whether ``path`` lies inside a folder whose every write this command records."""
    found = _find(Path(path) / "x")
    return found is not None and found[0].only is None


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
    if tmp is not None and abs_path(tmp) != abs_path(final):
        t = _find(Path(tmp))
        if t is not None and t[0] is s:
            ops.append({"t": t[1]})
    if data is not None:
        ops.append({"f": rel, "size": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    elif tmp is not None and Path(tmp).is_file():
        size, sha = sha256_file(Path(tmp))
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


# ---------------------------------------------------------------- recording writes

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
                size, sha = sha256_file(Path(dirpath) / f)
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
    now = [*sha256_file(path)]
    return [now] if now in versions else versions


def close(out: str | Path) -> None:
    """End the recording of ``out`` (the command is done with it): the manifest says ``closed``."""
    s = _SESSIONS.get(abs_path(out))
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
        s = _SESSIONS.pop(abs_path(out), None)
        if s is not None and s.journal_fh is not None:
            s.journal_fh.close()


def start_session(out: Path, command: str | None, keep: State | None = None, created: bool = False) -> None:
    """Mark ``out`` as ours from now on (manifest with status ``writing``) and record its writes; if
    the manifest cannot be written, ``out`` is removed again when this command ``created`` it."""
    root = abs_path(out)
    for r in [r for r in _SESSIONS if r == root or r.is_relative_to(root)]:
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
    open_session(root, None, command)


