"""What fishfmu wrote: the manifest of a folder, the journal of a command's writes, the atomic writers.

Every folder fishfmu writes into holds ``.fishfmu-manifest.json``: each file fishfmu wrote there
(path relative to the folder) with its size and SHA-256, and the folders it made.  Every file is
written under a temporary name (:func:`write_bytes_atomic`, :func:`write_file_atomic`,
:func:`write_tree_atomic`), then its size and SHA-256 are appended to ``.fishfmu-manifest.journal``
under both names (one JSON line, on disk *before* the rename), then it is renamed into place.  The
journal is folded into the manifest when the command ends; so a command killed outright (``kill -9``)
still leaves a folder whose every complete file is accounted for.  A temporary file a kill cut short
matches no record and is not fishfmu's: nothing is ours without its size and hash.

Both files are read strictly (:func:`fishfmu.output.manifest_state.load_state`): anything that is not what
fishfmu writes (not a regular file, not UTF-8, not JSON, an entry of the wrong shape, a path leaving the folder)
is bad input naming the file, and the folder is left alone.

A session records one command's writes into a whole folder (:func:`start_session`) or into some
single-file outputs of it (:func:`open_session`).  Which files are fishfmu's, and so may be written
over or removed, is decided from the manifest by :mod:`fishfmu.output.ownership`.

API: :func:`write_bytes_atomic`, :func:`write_file_atomic`, :func:`write_tree_atomic`, :func:`note_dir`,
the sessions (:func:`start_session`, :func:`open_session`, :func:`close`, :func:`close_all`).
"""

from __future__ import annotations

import atexit
import errno
import hashlib
import json
import os
import shutil
import stat
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Callable

from plant.errors import InputError

from fishfmu.output import lock
from fishfmu.output.manifest_state import (FORMAT, JOURNAL, MANIFEST, OutputError, State, is_internal, load_state,
                                           os_error, untrusted)


# ---------------------------------------------------------------- the manifest written

def _write_manifest(folder: Path, state: State) -> None:
    head = {"fishfmu_manifest": FORMAT, "status": state.status, "command": state.command}
    lines = [f" {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    lines.append(' "files": {' + ",".join(f"\n  {json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(state.files.items()))
                 + "\n },")
    lines.append(f' "dirs": {json.dumps(sorted(state.dirs))}')
    data = ("{\n" + "\n".join(lines) + "\n}\n").encode()
    _write_atomic(folder / MANIFEST, lambda fh: fh.write(data), _digest(data),
                  lambda tmp, size, sha: _append_journal(folder, [{"f": tmp.name, "size": size, "sha256": sha}]))


def sha256_file(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
    return size, h.hexdigest()


def _digest(data: bytes) -> tuple[int, str]:
    return len(data), hashlib.sha256(data).hexdigest()


# ---------------------------------------------------------------- the journal

def _open_journal(root: Path) -> IO[str]:
    """``root``'s journal, for appending: a regular file (never through a link); a line a kill tore
    is cut off first, so that what is appended starts a line of its own."""
    path = root / JOURNAL
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_NONBLOCK, 0o666)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.EISDIR):
            raise untrusted(path, "is not a regular file") from None
        raise os_error(exc, path) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise untrusted(path, "is not a regular file")
        if st.st_size:
            data = os.pread(fd, st.st_size, 0)
            if not data.endswith(b"\n"):
                os.ftruncate(fd, data.rfind(b"\n") + 1)
        return os.fdopen(fd, "a", encoding="utf-8")
    except OSError as exc:
        os.close(fd)
        raise os_error(exc, path) from None
    except BaseException:
        os.close(fd)
        raise


def _write_journal(fh: IO[str], ops: list[dict]) -> None:
    fh.write("".join(json.dumps(op) + "\n" for op in ops))
    fh.flush()
    os.fsync(fh.fileno())


def _append_journal(root: Path, ops: list[dict]) -> None:
    with _open_journal(root) as fh:
        _write_journal(fh, ops)


# ---------------------------------------------------------------- sessions: who records writes

@dataclass
class _Session:
    root: Path
    only: set[str] | None = None
    """None: the whole folder is this command's output; else just these file names in it"""
    command: str | None = None
    journal_fh: IO[str] | None = None


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
            s.journal_fh = _open_journal(s.root)
        _write_journal(s.journal_fh, ops)


def _dir_ops(rel: str) -> list[dict]:
    parts = rel.split("/")[:-1]
    return [{"d": "/".join(parts[:i])} for i in range(1, len(parts) + 1)]


def _note_written(tmp: Path, final: Path, size: int, sha: str) -> None:
    """Record, before the rename, that ``tmp`` and ``final`` hold the ``size`` bytes of hash ``sha``."""
    found = _find(final)
    if found is None:
        return
    s, rel = found
    if is_internal(rel):
        return
    ops = _dir_ops(rel)
    t = _find(tmp)
    if t is not None and t[0] is s:
        ops.append({"f": t[1], "size": size, "sha256": sha})
    ops.append({"f": rel, "size": size, "sha256": sha})
    _journal(s, ops)


# ---------------------------------------------------------------- the atomic writers

def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


_FILE_MODE, _DIR_MODE = 0o666 & ~_umask(), 0o777 & ~_umask()
"""mkstemp and mkdtemp make 0600 and 0700; an output is as readable as any file the user makes"""


def _write_atomic(path: Path, write: Callable[[IO[bytes]], object], digest: tuple[int, str] | None,
                  record: Callable[[Path, int, str], None]) -> None:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    except OSError as exc:
        raise os_error(exc, path) from None
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "w+b") as fh:
            os.fchmod(fh.fileno(), _FILE_MODE)
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        size, sha = digest if digest is not None else sha256_file(tmp)
        record(tmp, size, sha)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise os_error(exc, path) from None
        raise


def write_file_atomic(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Write ``path`` with ``write(fh)`` (a binary file, seekable: what a library writes) under a
    temporary name, record both names with the size and SHA-256 of what is on disk, rename into place.
    An OS error (read-only, disk full, not a folder) is an :class:`OutputError`."""
    _write_atomic(path, write, None, lambda tmp, size, sha: _note_written(tmp, Path(path), size, sha))


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """:func:`write_file_atomic` of the bytes ``data``."""
    _write_atomic(path, lambda fh: fh.write(data), _digest(data),
                  lambda tmp, size, sha: _note_written(tmp, Path(path), size, sha))


def write_tree_atomic(final: Path, write: Callable[[Path], object]) -> None:
    """A folder another library writes (``write(folder)``): made under a temporary name (a folder of
    ours), every file in it recorded with its size and SHA-256 under both names, renamed to
    ``final`` (which must not exist)."""
    final = Path(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".part"))
        os.chmod(tmp, _DIR_MODE)
    except OSError as exc:
        raise os_error(exc, final) from None
    note_dir(tmp)
    try:
        write(tmp)
        _record_tree(tmp, final)
        os.replace(tmp, final)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)  # made by mkdtemp just now, written only by ``write``
        if isinstance(exc, OSError):
            raise os_error(exc, final) from None
        raise


def _record_tree(src: Path, final: Path) -> None:
    """Before ``os.replace(src, final)`` of a folder: record each file under both names."""
    found = _find(final / "x")
    if found is None:
        return
    ops = _dir_ops(found[1])
    for dirpath, dirnames, filenames in os.walk(src):
        rel_dir = Path(dirpath).relative_to(src)
        for base in (src, final):
            for d in dirnames:
                fr = _find(base / rel_dir / d / "x")
                if fr is not None:
                    ops += _dir_ops(fr[1])
        for f in filenames:
            size, sha = sha256_file(Path(dirpath) / f)
            for base in (src, final):
                fr = _find(base / rel_dir / f)
                if fr is not None:
                    ops.append({"f": fr[1], "size": size, "sha256": sha})
    _journal(found[0], ops)


def note_dir(path: str | Path) -> None:
    """Record a folder this command made (kept even while empty; removed only when empty)."""
    found = _find(Path(path) / "x")
    if found is not None:
        _journal(found[0], _dir_ops(found[1]))


def _close(s: _Session, status: str | None = "closed", unlock: bool = True) -> None:
    """Fold the journal into the manifest (files gone are dropped), then remove the journal; then, ``unlock``,
    let go of the folder's lock (:mod:`fishfmu.output.lock`): the command is done with it."""
    try:
        _fold(s, status)
    finally:
        if unlock:
            lock.release(s.root)


def _fold(s: _Session, status: str | None) -> None:
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
        except (OSError, InputError):
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
        _close(_SESSIONS[r], unlock=r != root)  # ``out``'s own lock is the new session's
    state = keep if keep is not None else State()
    state.present, state.status, state.command = True, "writing", command
    try:
        _write_manifest(out, state)
        (out / JOURNAL).unlink(missing_ok=True)  # folded into the manifest just written
    except OutputError:
        if created:  # this command made the folder: its journal is ours; a folder of the user's stays, even empty
            (out / JOURNAL).unlink(missing_ok=True)
            if not any(out.iterdir()):
                out.rmdir()
        raise
    open_session(root, None, command)
