"""One fishfmu command as a process: its temporary folder, its worker processes, and Ctrl-C.

The commands with worker processes (``run --seeds``, ``sweep``, ``compare``, ``diagnose``) run
inside :func:`session` (``fishfmu.cli.main`` opens one for every command): there the first SIGINT or
SIGTERM raises :class:`Interrupted` in the main thread, so that a loop waiting for workers stops at
once, cancels what has not run, shuts its cluster or pool down and writes what finished; the session
owns the command's temporary folder (``TMPDIR`` of the command and its workers), removes it at the
end and terminates any child process still alive.  The output folder a command registers
(:func:`register_output`) is marked ``partial`` when it is stopped.  A single run stops between two
steps instead (:mod:`fishfmu.cosim.stop`).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fishfmu.cosim.stop import SIGNALS, StopRequest

# ---------------------------------------------------------------- commands with worker processes

class Interrupted(BaseException):
    """Raised in the main thread by the first SIGINT/SIGTERM inside :func:`session` (outside a
    :func:`deferred_signals` block, where it is raised at the block's end).

    A BaseException, not an Exception, so that ``except Exception`` (a failed run, a bug) never
    swallows it; not a KeyboardInterrupt, so that the command-line framework does not turn it into
    exit code 1.  ``partial`` may carry what had finished when it was raised.
    """

    def __init__(self, signum: int, partial: Any = None) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.partial = partial

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name


STOPS = (KeyboardInterrupt, Interrupted)
"""What a loop over worker results catches to stop early (Ctrl-C without a session, or a session's signal)."""


class Session(StopRequest):
    """One command's ownership of its temporary folder and worker processes (see :func:`session`)."""

    def __init__(self, tmp: Path, before: set[int]) -> None:
        super().__init__()
        self.tmp = tmp
        """the temporary folder every process of the command uses (``TMPDIR``); removed at the end"""
        self.out_dir: Path | None = None
        """the output folder, once made: marked ``partial`` when the command is stopped"""
        self.out_info: dict[str, Any] = {}
        """what ``run_info.json`` says if the command had not written one yet"""
        self._raised = False
        self._deferred = 0
        self._before = before
        self._seen: list[Any] = []


_current: Session | None = None


def current() -> Session | None:
    """The session of this command, if any (None when fishfmu is used as a library)."""
    return _current


def register_output(out_dir: Path, info: dict[str, Any] | None = None) -> None:
    """Tell the session which folder to mark ``partial`` if the command is stopped (``info``: what
    its ``run_info.json`` says, if the command has not written one by then)."""
    if _current is not None:
        _current.out_dir = Path(out_dir)
        _current.out_info = dict(info or {})


def raise_if_stopped() -> None:
    """Raise :class:`Interrupted` now if a signal came while it could not be raised."""
    s = _current
    if s is not None and s.signum is not None and not s._raised and s._deferred == 0:
        s._raised = True
        raise Interrupted(s.signum)


@contextmanager
def deferred_signals() -> Iterator[None]:
    """A block a signal does not break into (starting a cluster or a pool): the signal is raised at its end.

    An error in the block after a signal (a worker killed by it while starting) counts as the signal.
    """
    s = _current
    if s is not None:
        s._deferred += 1
    try:
        yield
    except Exception as exc:
        if s is not None and s.signum is not None and not s._raised:
            s._raised = True
            raise Interrupted(s.signum) from exc
        raise
    finally:
        if s is not None:
            s._deferred -= 1
    raise_if_stopped()


def _descendants() -> list[Any]:
    import psutil
    try:
        return psutil.Process().children(recursive=True)
    except psutil.Error:
        return []


def reap(procs: list[Any], grace_s: float = 3.0) -> None:
    """Terminate these processes (psutil), then kill what is left after ``grace_s``."""
    import psutil
    alive = []
    for p in procs:
        try:
            if p.is_running():  # also False when the pid now belongs to another process
                p.terminate()
                alive.append(p)
        except psutil.Error:
            pass
    _, left = psutil.wait_procs(alive, timeout=grace_s)
    for p in left:
        with contextlib.suppress(psutil.Error):
            p.kill()
    psutil.wait_procs(left, timeout=1.0)


def mark_partial(out_dir: Path | None, signum: int, info: dict[str, Any] | None = None) -> None:
    """Set ``status`` to ``partial`` in ``out_dir/run_info.json``, written with ``info`` if the
    folder holds none yet (nothing happens when the folder does not exist)."""
    if out_dir is None or not Path(out_dir).is_dir():
        return
    info_path = Path(out_dir) / "run_info.json"
    try:
        info = json.loads(info_path.read_text())
    except FileNotFoundError:
        info = dict(info or {})
    except (OSError, ValueError):
        return
    if not isinstance(info, dict) or info.get("status") == "partial":
        return
    info.update(status="partial", stopped_by=signal.Signals(signum).name)
    from fishfmu.output.atomic import write_run_info
    with contextlib.suppress(OSError):
        write_run_info(out_dir, **info)


def _spawn_ignoring_sigint(spawn: Any) -> Any:
    """multiprocessing's spawn (fork + exec of a worker) with SIGINT blocked in the spawning thread
    for the moment of the fork: the signal mask survives fork and exec, so the worker starts with
    SIGINT blocked and a Ctrl-C to the process group cannot kill a worker that is still starting
    (importing for seconds); the worker is stopped by the command (SIGTERM, then SIGKILL).  Any
    thread may spawn (Dask's event loop does); the mask is per thread, so the command's own handler
    keeps working in the main thread."""

    def wrapped(path, args, passfds):  # noqa: ANN001, ANN202
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            return spawn(path, args, passfds)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)

    wrapped.fishfmu_wraps = spawn
    return wrapped


@contextmanager
def session(signals: tuple[int, ...] = SIGNALS, prefix: str = "fishfmu-") -> Iterator[Session]:
    """Run a command so that SIGINT/SIGTERM stop it cleanly, with its worker processes and temporary files.

    - Every temporary file of the command and of the processes it starts (unpacked FMUs, Dask's
      scratch space, FMU worker processes) goes into one folder made here (``TMPDIR`` and
      :data:`tempfile.tempdir` point to it); the folder is removed at the end, whatever happened.
    - The first signal raises :class:`Interrupted` in the main thread: loops over worker results
      stop, cancel what has not run, shut their pools and clusters down and write what finished.
    - Worker processes (multiprocessing spawn: Dask workers, process pools) ignore SIGINT from
      their start (:func:`_spawn_ignoring_sigint`; elsewhere than Linux from the moment they import
      fishfmu, ``FISHFMU_SESSION`` is set for them): a Ctrl-C to the process group is the
      command's, which stops them in order; none dies of it half-started.
    - Child processes started inside the block and still alive at its end (or at the signal) are
      terminated, then killed.
    - A second signal stops at once: the children are killed, the folder removed, the process
      ends by the signal (exit status 128 + its number).

    Handlers can only be set from the main thread; elsewhere only the folder is managed.
    """
    global _current
    tmp = Path(tempfile.mkdtemp(prefix=prefix))
    s = Session(tmp, {p.pid for p in _descendants()})
    old_env, old_tempdir = os.environ.get("TMPDIR"), tempfile.tempdir
    old_session = os.environ.get("FISHFMU_SESSION")
    os.environ["TMPDIR"] = str(tmp)
    os.environ["FISHFMU_SESSION"] = str(tmp)  # worker processes ignore Ctrl-C from the start (fishfmu/__init__.py)
    tempfile.tempdir = str(tmp)
    main = threading.current_thread() is threading.main_thread()
    previous = {sig: signal.getsignal(sig) for sig in signals} if main else {}

    def ours(procs: list[Any]) -> list[Any]:
        return [p for p in procs if p.pid not in s._before]

    def handler(signum: int, _frame) -> None:  # noqa: ANN001
        if s.signum is None:
            s.signum = signum
            s._seen = ours(_descendants())  # orphans-to-be: a worker's own children outlive a killed worker
            if s._deferred == 0:
                s._raised = True
                raise Interrupted(signum)
            return
        # second signal: no more waiting
        for p in ours(_descendants()) + s._seen:
            with contextlib.suppress(Exception):
                p.kill()
        shutil.rmtree(tmp, ignore_errors=True)
        mark_partial(s.out_dir, s.signum, s.out_info)
        for sig in previous:
            signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    for sig in previous:
        signal.signal(sig, handler)
    import multiprocessing.util as mp_util
    original_spawn = mp_util.spawnv_passfds
    if main and sys.platform == "linux" and not hasattr(original_spawn, "fishfmu_wraps"):
        mp_util.spawnv_passfds = _spawn_ignoring_sigint(original_spawn)
    _current = s
    try:
        yield s
    finally:
        if s.signum is None:  # the clean-up below is not to be broken into
            s._deferred += 1
        try:
            reap(ours(_descendants()) + s._seen)
            shutil.rmtree(tmp, ignore_errors=True)
        finally:
            _current = None
            mp_util.spawnv_passfds = original_spawn
            if old_env is None:
                os.environ.pop("TMPDIR", None)
            else:
                os.environ["TMPDIR"] = old_env
            tempfile.tempdir = old_tempdir
            if old_session is None:
                os.environ.pop("FISHFMU_SESSION", None)
            else:
                os.environ["FISHFMU_SESSION"] = old_session
            for sig, h in previous.items():
                signal.signal(sig, h)
