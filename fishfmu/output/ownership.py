"""Which files in an output location are fishfmu's, and the rules that keep everything else safe.

What fishfmu wrote is recorded in each folder's manifest (:mod:`fishfmu.output.manifest`); nothing
else proves ownership (a ``run_info.json`` is just a file).  The rules built on it:

* An output folder that exists and is not empty is accepted only if every entry in it is ours:
  a file listed in the manifest with the same size and hash (a file of ours that was changed is no
  longer ours; a temporary file is ours the same way, so one a kill cut short is not), or a folder
  whose entries are all ours.  A symbolic link is never ours (fishfmu writes none) and is never
  followed.  Otherwise the command stops with exit 2 naming the first foreign file, and nothing is
  touched; a manifest or journal fishfmu did not write as it writes them is exit 2 naming it.
* A folder of ours that holds an earlier result is replaced only with ``--overwrite`` (the default
  folder too): exactly the files in the manifest are removed, then the folders fishfmu made if
  they are empty (a folder is only ever removed empty, and only one fishfmu made); never a whole
  tree.  A command that crashed or was killed left only files of ours (and perhaps a temporary
  file it cut short, which is not ours), so its folder is replaceable the same way.
* ``sweep`` resumes into a folder of ours and keeps what is there (:func:`open_resumable`).
* An output folder must not be, hold, or lie inside an input (scenario, FMU, dataset).
* A single-file output (``--junit``, ``replay --out``, ``bench --json/--plot``, a built ``.fmu``)
  may replace an existing file only if the manifest of the file's folder lists it unchanged,
  and never one of the command's inputs; the file is then recorded there (the folder gets a
  manifest listing just that file if it had none).

API: :func:`prepare_out_dir`, :func:`open_resumable`, :func:`check_single_file_target`,
:func:`first_foreign`, :func:`check_not_input`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path

from plant.errors import InputError

from fishfmu.output import lock
from fishfmu.output.manifest import (abs_path, forget, inside_folder_being_written, note_dir, open_session, sha256_file,
                                     start_session)
from fishfmu.output.manifest_state import OutputError, State, is_internal, is_temporary_name, load_state, os_error


# ---------------------------------------------------------------- ownership of a folder

@dataclass
class Scan:
    foreign: str | None = None
    """the first entry that is not ours, with why ('notes.txt (not written by fishfmu)')"""
    files: list[str] = field(default_factory=list)
    """our files, temporary ones included (relative paths)"""
    dirs: list[str] = field(default_factory=list)


_NOT_OURS = ("a temporary name, but not a file fishfmu recorded with this size and hash: left by a write that was "
             "killed? remove it yourself")


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
            if rel not in state.files:
                result.foreign = f"{rel} ({_NOT_OURS})" if is_temporary_name(rel) else f"{rel} (not written by fishfmu)"
                return False
            if [*sha256_file(Path(e.path))] not in state.files[rel]:
                result.foreign = f"{rel} ({_NOT_OURS})" if is_temporary_name(rel) else \
                    f"{rel} (changed since fishfmu wrote it)"
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
        if rel in state.dirs:
            try:
                (out / rel).rmdir()
            except OSError:
                pass  # not empty (an empty folder we did not make is left)
    for name in os.listdir(out):
        if is_internal(name):
            (out / name).unlink(missing_ok=True)


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
    created = not out.exists() and _create(out)
    with _locked(out):
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
        start_session(out, command, created=_create(out) or created)
    return out


@contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Hold ``out``'s lock (:mod:`fishfmu.output.lock`) from before its contents are looked at; the session the
    block starts keeps it until the command ends (:func:`fishfmu.output.manifest.close`), a refusal lets it go."""
    held_before = lock.holds(out)
    lock.acquire(out)
    try:
        yield
    except BaseException:
        if not held_before:
            lock.release(out)
        raise


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
    if inside_folder_being_written(out):
        if out.exists() and not out.is_dir():
            raise InputError("exists and is not a folder", file=out)
        _create(out)
        note_dir(out)
        return out
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=out)
    created = not out.exists() and _create(out)
    with _locked(out):
        state = load_state(out)
        if [n for n in os.listdir(out) if not is_internal(n)]:
            found_scan = scan(out, state)
            if found_scan.foreign:
                raise _refuse_foreign(out, found_scan.foreign)
            _remove_temporary(out, found_scan, state)
        start_session(out, command, keep=state if state.present else None,
                      created=_create(out) or created)
    return out


def _remove_temporary(out: Path, found: Scan, state: State) -> None:
    """The temporary files of ours that a command stopped in the middle of a write left (each recorded with its
    size and hash: ours), and the temporary folders we made once empty: a resumed folder keeps its results only."""
    for rel in [r for r in found.files if is_temporary_name(r)]:
        try:
            (out / rel).unlink(missing_ok=True)
        except OSError as exc:
            raise os_error(exc, out / rel, "cannot remove a temporary file of an earlier write") from None
        state.files.pop(rel, None)
    for rel in sorted((d for d in found.dirs if is_temporary_name(d) and d in state.dirs), key=lambda r: -r.count("/")):
        try:
            (out / rel).rmdir()
            state.dirs.discard(rel)
        except OSError:
            pass  # not empty (what is left in it is not ours: kept)


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
        if same or abs_path(path) == i.resolve():
            raise InputError(f"is an input of this command ({inp}); refusing to write over it", file=path)
        if i.is_dir() and _within(abs_path(path), i.resolve()):
            raise InputError(f"lies inside the input folder {inp}; refusing to write there", file=path)
    if path.is_symlink():
        raise InputError("is a symbolic link, not written by fishfmu; refusing to write over it", file=path)
    # the folder's manifest records this write: one command at a time writes it
    with _locked(path.parent) if path.parent.is_dir() else nullcontext():
        state = load_state(path.parent) if path.parent.is_dir() else State()  # a malformed manifest stops us here
        if path.exists():
            if not path.is_file():
                raise InputError("exists and is not a file", file=path)
            if path.name not in state.files or [*sha256_file(path)] not in state.files[path.name]:
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
        open_session(abs_path(path).parent, only=path.name)
    return path
