"""One command at a time on an output folder: an advisory lock held on the folder itself.

A command that writes a folder (``run``, ``run --seeds``, ``serve``, ``sweep``, ``compare``, ``diagnose``,
``calibrate``) locks it (``flock``, exclusive) before it looks at what is in it, and holds the lock until its
manifest is folded at the end (:func:`fishfmu.output.manifest.close`).  A second command on the folder is refused
at once, naming the process that holds it: without the lock the two removed and wrote each other's files and
left a folder whose files no manifest listed (issue 39).

The lock is taken on the folder's own file descriptor, not on a lock file: it writes nothing, so it may be taken
on a folder that turns out not to be fishfmu's (which is then refused untouched).  The kernel drops it when the
process ends, however it ends (``kill -9`` too): a killed command never leaves a stale lock.  The descriptor is
not inherited by worker processes (Python opens it close-on-exec; workers are spawned, FMU workers exec'd), so a
worker outliving its command does not hold the folder.
"""

from __future__ import annotations

import fcntl
import os
import threading
from pathlib import Path

from plant.errors import InputError

from fishfmu.output.manifest_state import os_error

_HELD: dict[Path, int] = {}
"""folder (absolute) -> the descriptor this process holds its lock on"""
_LOCK = threading.Lock()


class FolderInUse(InputError):
    """Another process holds the output folder's lock: exit 2, nothing touched."""


def _key(folder: Path) -> Path:
    return Path(os.path.realpath(folder))


def acquire(folder: Path) -> None:
    """Lock the existing folder ``folder`` for this process (again: nothing happens), or raise
    :class:`FolderInUse` naming the process that holds it."""
    key = _key(folder)
    with _LOCK:
        if key in _HELD:
            return
        try:
            fd = os.open(key, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as exc:
            raise os_error(exc, folder, "cannot open the output folder") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(os.fstat(fd))
            os.close(fd)
            raise FolderInUse(f"output folder is in use by {holder}; nothing was touched; wait for it to end, "
                              "or choose another --out", file=folder) from None
        except BaseException:
            os.close(fd)
            raise
        _HELD[key] = fd


def release(folder: Path) -> None:
    """Let go of ``folder``'s lock if this process holds it."""
    with _LOCK:
        fd = _HELD.pop(_key(folder), None)
    if fd is not None:
        os.close(fd)  # closing the last descriptor of the open file drops its flock


def holds(folder: Path) -> bool:
    return _key(folder) in _HELD


def _holder(st: os.stat_result) -> str:
    """'another fishfmu command (pid 123: fishfmu run a.toml --out x)': the pid from ``/proc/locks`` (Linux), its
    command line from ``/proc/<pid>/cmdline``; less when either cannot be read."""
    dev = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    pid = None
    try:
        with open("/proc/locks", encoding="ascii", errors="replace") as fh:
            for line in fh:
                parts = line.split()
                # "1: FLOCK  ADVISORY  WRITE 1234 08:01:5678 0 EOF" ("->" before a waiter's entry)
                if "->" not in parts and len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == dev:
                    pid = int(parts[4])
                    break
    except (OSError, ValueError):
        pass
    if pid is None:
        return "another fishfmu command"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            args = [a.decode(errors="replace") for a in fh.read().split(b"\0") if a]
    except OSError:
        args = []
    # "python -m fishfmu ..." or ".../bin/fishfmu ...": shown from "fishfmu" on
    start = next((i for i, a in enumerate(args) if Path(a).name == "fishfmu" or a == "fishfmu.cli"), None)
    shown = " ".join(["fishfmu", *args[start + 1:]] if start is not None else args)
    if len(shown) > 120:
        shown = shown[:117] + "..."
    return f"another fishfmu command (pid {pid}: {shown})" if shown else f"another fishfmu command (pid {pid})"
