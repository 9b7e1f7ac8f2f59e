"""The manifest and journal as files: their names and format, what they say (:class:`State`), and reading them
strictly (:func:`load_state`) from a folder that may hold anything; and the error an output location gives.

A manifest or journal that is not what fishfmu writes (not a regular file, not UTF-8, not JSON, an entry of
the wrong shape, a path leaving the folder) is bad input naming the file (:func:`untrusted`): fishfmu then
cannot tell which files are its own, and touches none.  Writing them: :mod:`fishfmu.output.manifest`.
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant.errors import InputError

MANIFEST = ".fishfmu-manifest.json"
JOURNAL = ".fishfmu-manifest.journal"
FORMAT = 1
MAX_SIZE = 2**63 - 1
"""the largest file size a manifest may state (st_size is a signed 64-bit count)"""
_SHA256 = re.compile(r"[0-9a-f]{64}")


@dataclass
class OutputError(InputError):
    """An output location that cannot be written (not a folder, read-only, disk full): exit 2."""


def os_error(exc: OSError, path: str | Path, doing: str = "cannot write") -> OutputError:
    """One line naming the path and the OS error."""
    why = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        why = "no space left on device"
    return OutputError(f"{doing}: {why}", file=path)



@dataclass
class State:
    """What a folder's manifest (and journal) say."""

    present: bool = False
    status: str | None = None
    command: str | None = None
    files: dict[str, list[list]] = field(default_factory=dict)
    """relative path -> [size, sha256] versions fishfmu wrote there (the newest last); temporary names too"""
    dirs: set[str] = field(default_factory=set)
    """folders fishfmu made (removed only when empty)"""

    def add_file(self, rel: str, size: int, sha: str) -> None:
        versions = self.files.setdefault(rel, [])
        if [size, sha] in versions:
            versions.remove([size, sha])
        versions.append([size, sha])


def is_internal(name: str) -> bool:
    """The manifest and its journal (a name at the top of a folder)."""
    return name in (MANIFEST, JOURNAL)


def is_temporary_name(rel: str) -> bool:
    """Named like fishfmu's temporary files and folders (``.<name>.<random>.part``), or inside one."""
    return any(p.startswith(".") and p.endswith(".part") for p in rel.split("/"))


class _Bad(ValueError):
    """What is wrong with one entry of a manifest or journal."""


def untrusted(path: Path, what: str, where: str | None = None) -> InputError:
    return InputError(f"{what}; fishfmu cannot tell which files in this folder are its own, so nothing was "
                      "touched (choose another output, or remove or repair this file)", file=path, where=where)


def _show(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _rel(v: Any, what: str) -> str:
    """A path relative to the folder, inside it: no empty, ``.`` or ``..`` part, nothing absolute."""
    if not isinstance(v, str) or not v:
        raise _Bad(f"{what} {_show(v)} is not a path")
    try:
        os.fsencode(v)
    except UnicodeError:
        raise _Bad(f"{what} {_show(v)} is not a file name") from None
    if "\0" in v or any(p in ("", ".", "..") for p in v.split("/")):
        raise _Bad(f"{what} {_show(v)} is not a relative path inside the folder")
    return v


def _size(v: Any, what: str) -> int:
    if type(v) is not int or not 0 <= v <= MAX_SIZE:
        raise _Bad(f"{what}: size {_show(v)} is not a whole number of bytes (0 to {MAX_SIZE})")
    return v


def _sha(v: Any, what: str) -> str:
    if not isinstance(v, str) or not _SHA256.fullmatch(v):
        raise _Bad(f"{what}: sha256 {_show(v)} is not 64 lower-case hex digits")
    return v


def _read_internal(path: Path) -> str | None:
    """The text of the manifest or journal ``path`` (None if there is none); one that is not a regular
    file or not UTF-8 is untrusted.  Opened without following a link or blocking on a FIFO."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise untrusted(path, "is a symbolic link, not a file fishfmu wrote") from None
        raise os_error(exc, path, "cannot read") from None
    try:
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise untrusted(path, "is not a regular file")
            data = fh.read()
    except IsADirectoryError:
        raise untrusted(path, "is not a regular file") from None
    except OSError as exc:
        raise os_error(exc, path, "cannot read") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise untrusted(path, f"is not UTF-8 text (byte {exc.start})") from None


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except RecursionError:
        raise _Bad("is nested too deeply to be a fishfmu record") from None
    except ValueError as exc:
        raise _Bad(f"is not JSON ({exc})") from None


def _read_manifest(doc: Any, state: State) -> None:
    if not isinstance(doc, dict) or type(doc.get("fishfmu_manifest")) is not int or doc["fishfmu_manifest"] != FORMAT:
        raise _Bad(f"is not a fishfmu manifest of format {FORMAT}")
    unknown = set(doc) - {"fishfmu_manifest", "status", "command", "files", "temps", "dirs"}
    if unknown:
        raise _Bad(f"has an unknown key {_show(sorted(unknown)[0])}")
    for key in ("status", "command"):
        if not isinstance(doc.get(key), (str, type(None))):
            raise _Bad(f'"{key}" {_show(doc[key])} is not text')
    files, dirs, temps = doc.get("files", {}), doc.get("dirs", []), doc.get("temps", [])
    if not isinstance(files, dict):
        raise _Bad('"files" is not an object')
    for rel, versions in files.items():
        what = f'"files" entry {_show(rel)}'
        _rel(rel, '"files" entry')
        if not isinstance(versions, list) or not versions:
            raise _Bad(f"{what} is not a list of [size, sha256]")
        for v in versions:
            if not isinstance(v, list) or len(v) != 2:
                raise _Bad(f"{what} is not a list of [size, sha256]")
            state.add_file(rel, _size(v[0], what), _sha(v[1], what))
    for key, names in (("dirs", dirs), ("temps", temps)):
        if not isinstance(names, list):
            raise _Bad(f'"{key}" is not a list')
        for rel in names:
            _rel(rel, f'"{key}" entry')
    state.dirs.update(dirs)
    # "temps" (earlier fishfmu versions) named temporary files without size or hash: that proves nothing
    state.status, state.command = doc.get("status"), doc.get("command")


def _read_journal_line(op: Any, state: State) -> None:
    keys = set(op) if isinstance(op, dict) else None
    if keys == {"f", "size", "sha256"}:
        what = f"file {_show(op['f'])}"
        state.add_file(_rel(op["f"], "file"), _size(op["size"], what), _sha(op["sha256"], what))
    elif keys == {"d"}:
        state.dirs.add(_rel(op["d"], "folder"))
    elif keys == {"t"}:
        _rel(op["t"], "temporary name")  # an older fishfmu's temporary name alone: proves nothing
    else:
        raise _Bad(f"{_show(op)} is not a journal entry")


def load_state(folder: Path) -> State:
    """What ``folder``'s manifest and journal say; either one malformed is an :class:`InputError`
    naming it (and where in it), so that nothing is removed on its word."""
    state = State()
    m = folder / MANIFEST
    text = _read_internal(m)
    if text is not None:
        try:
            _read_manifest(_json(text), state)
        except _Bad as exc:
            raise untrusted(m, str(exc)) from None
        state.present = True
    j = folder / JOURNAL
    text = _read_internal(j)
    if text is not None:
        state.present = True  # a command that wrote here was killed before folding its journal in
        lines = text.split("\n")
        for n, line in enumerate(lines, 1):
            if n == len(lines) and not line:
                break
            try:
                op = _json(line)
            except _Bad as exc:
                if n == len(lines):
                    break  # the last line, torn by a kill: what it announced was not renamed into place yet
                raise untrusted(j, str(exc), f"line {n}") from None
            try:
                _read_journal_line(op, state)
            except _Bad as exc:
                raise untrusted(j, str(exc), f"line {n}") from None
    return state
