"""One fishfmu command as a process: its signals, its temporary folder and its worker processes.

The one place where fishfmu's own process answers SIGINT and SIGTERM (a worker process only ignores
SIGINT, so that a Ctrl-C to the process group is the command's to handle).  The first signal is
answered in one of two ways, by what the command is doing when it comes:

- a loop waiting for worker processes (``run --seeds``, ``sweep``, ``compare``, ``diagnose``,
  ``calibrate``) gets :class:`Interrupted` in the main thread: it stops at once, cancels what has not
  run, shuts its cluster or pool down and writes what finished (inside :func:`deferred_signals` the
  exception waits for the end of the block);
- a loop that steps a run (``run``, ``serve``) inside :func:`stop_between_steps` is only asked to stop:
  it polls ``requested`` between two steps, ends after the current one and writes what there is.

A second signal stops at once: child processes are killed, the temporary folder removed, the command's
output folder told (``run_info.json`` says ``partial``) and the process ends by the signal.

Every command runs inside :func:`session` (``fishfmu.cli.main`` opens one): it owns the command's
temporary folder (``TMPDIR`` of the command and its workers), removes it at the end and terminates any
child process still alive.  The output folder a command registers (:func:`register_output`, done by
:class:`fishfmu.output.run_folder.RunFolder`) is told when a signal ends the command.  fishfmu used as a
library has no session: :func:`stop_between_steps` then takes the signals for its block alone.
"""

from __future__ import annotations

import contextlib
import multiprocessing.util as mp_util
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import psutil

from fishfmu.cosim.stop import StopRequest, exit_status

SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals that stop a command."""


class Interrupted(BaseException):
    """Raised in the main thread by the first SIGINT/SIGTERM inside :func:`session` (outside a
    :func:`deferred_signals` block, where it is raised at the block's end, and outside
    :func:`stop_between_steps`, where it is not raised at all).

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
        return exit_status(self.signum)

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name


STOPS = (KeyboardInterrupt, Interrupted)
"""What a loop over worker results catches to stop early (Ctrl-C without a session, or a session's signal)."""


class Session(StopRequest):
    """One command's signals, temporary folder and worker processes (see :func:`session`); the stop request
    a stepping loop polls (:func:`stop_between_steps`)."""

    def __init__(self, tmp: Path | None, before: set[int]) -> None:
        super().__init__()
        self.tmp = tmp
        """the temporary folder every process of the command uses (``TMPDIR``); removed at the end (None: a
        library's :func:`stop_between_steps` block, which has none)"""
        self.out_dir: Path | None = None
        """the command's output folder, once registered (:func:`register_output`)"""
        self.on_stopped: Callable[[int], None] | None = None
        """what tells that folder a signal ended the command (``run_info.json``: ``partial``)"""
        self._raised = False
        self._deferred = 0
        self._polled = 0
        self._before = before
        self._seen: list[Any] = []

    def ours(self, procs: list[Any]) -> list[Any]:
        """The processes of ``procs`` started since the session began."""
        return [p for p in procs if p.pid not in self._before]

    def tell_output(self, signum: int) -> None:
        """Tell the registered output folder that the signal ``signum`` ended the command."""
        if self.on_stopped is not None:
            self.on_stopped(signum)


_current: Session | None = None


def current() -> Session | None:
    """The session of this command, if any (None when fishfmu is used as a library)."""
    return _current


def register_output(out_dir: Path, on_stopped: Callable[[int], None]) -> None:
    """Make ``out_dir`` the command's output folder, told by ``on_stopped(signum)`` when a signal ends the command
    (an exception :class:`Interrupted` leaving the session, or a second signal).  The first folder registered is
    the command's (``run --seeds`` writes a sweep into a folder of its own); outside a session nothing happens."""
    if _current is not None and _current.out_dir is None:
        _current.out_dir, _current.on_stopped = Path(out_dir), on_stopped


def raise_if_stopped() -> None:
    """Raise :class:`Interrupted` now if a signal came while it could not be raised."""
    s = _current
    if s is not None and s.signum is not None and not s._raised and s._deferred == 0 and s._polled == 0:
        s._raised = True
        raise Interrupted(s.signum)


def raise_if_signalled() -> None:
    """Raise :class:`Interrupted` if a signal came, also when its exception was raised already but lost: raised in
    Python code that Exudyn's step called, it can be swallowed there, and the command would go on as if no signal
    had come. Called where a step loop's work returned normally (nothing is unwinding)."""
    s = _current
    if s is not None and s.signum is not None and s._deferred == 0 and s._polled == 0:
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


@contextmanager
def stop_between_steps() -> Iterator[StopRequest]:
    """A block whose loop steps a run: the first SIGINT/SIGTERM only sets ``requested`` on the request yielded,
    which the loop polls between two steps (:func:`fishfmu.cosim.runner.run_scenario`, the served line); the
    command then writes what there is, marked ``partial``.  A second signal stops at once.

    Inside a session the request is the session's; outside one (fishfmu used as a library, in the main thread)
    the block takes the signals for itself, and a second one goes to the handler from before the block."""
    s = _current
    if s is None:
        s = Session(None, {p.pid for p in _descendants()})
        s._polled = 1
        with _answer_signals(s, SIGNALS, second_to_previous=True):
            yield s
        return
    s._polled += 1
    try:
        yield s
    finally:
        s._polled -= 1
        if s.signum is not None:
            s._raised = True  # answered by the loop, which stopped: not raised again


def _descendants() -> list[Any]:
    try:
        return psutil.Process().children(recursive=True)
    except psutil.Error:
        return []


def reap(procs: list[Any], grace_s: float = 3.0) -> None:
    """Terminate these processes (psutil), then kill what is left after ``grace_s``."""
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


@contextmanager
def _answer_signals(s: Session, signals: tuple[int, ...], second_to_previous: bool) -> Iterator[None]:
    """The handler of ``signals`` for the block (main thread only: elsewhere none can be set; the block then only
    manages what it owns).  The first signal sets ``s.signum`` and raises :class:`Interrupted` unless the session
    defers it or a loop polls for it; the second kills the session's child processes, removes its temporary
    folder, tells its output folder, and delivers itself again to the default handler (the process ends by it),
    or with ``second_to_previous`` to the handler from before the block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in signals}

    def handler(signum: int, _frame) -> None:  # noqa: ANN001
        if s.signum is None:
            s.signum = signum
            s._seen = s.ours(_descendants())  # orphans-to-be: a worker's own children outlive a killed worker
            if s._deferred == 0 and s._polled == 0:
                s._raised = True
                raise Interrupted(signum)
            return
        # second signal: no more waiting
        for p in s.ours(_descendants()) + s._seen:
            with contextlib.suppress(Exception):
                p.kill()
        if s.tmp is not None:
            shutil.rmtree(s.tmp, ignore_errors=True)
        with contextlib.suppress(Exception):
            s.tell_output(s.signum)
        for sig, h in previous.items():
            signal.signal(sig, h if second_to_previous else signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    for sig in signals:
        signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, h in previous.items():
            signal.signal(sig, h)


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
    - The first signal raises :class:`Interrupted` in the main thread (see the module docstring for
      :func:`deferred_signals` and :func:`stop_between_steps`): loops over worker results stop, cancel
      what has not run, shut their pools and clusters down and write what finished.  When it leaves
      the block, the registered output folder is told (``run_info.json``: ``partial``).
    - Worker processes (multiprocessing spawn: Dask workers, process pools) ignore SIGINT from
      their start (:func:`_spawn_ignoring_sigint`; elsewhere than Linux from the moment they import
      fishfmu, ``FISHFMU_SESSION`` is set for them): a Ctrl-C to the process group is the
      command's, which stops them in order; none dies of it half-started.
    - Child processes started inside the block and still alive at its end (or at the signal) are
      terminated, then killed.
    - A second signal stops at once: the children are killed, the folder removed, the output folder
      told, and the process ends by the signal (exit status 128 + its number).

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
    original_spawn = mp_util.spawnv_passfds
    main = threading.current_thread() is threading.main_thread()
    if main and sys.platform == "linux" and not hasattr(original_spawn, "fishfmu_wraps"):
        mp_util.spawnv_passfds = _spawn_ignoring_sigint(original_spawn)
    _current = s
    try:
        with _answer_signals(s, signals, second_to_previous=False):
            try:
                yield s
            except Interrupted as exc:  # the command ends by the signal: its output folder says partial
                s.tell_output(exc.signum)
                raise
            finally:
                if s.signum is None:  # the clean-up below is not to be broken into
                    s._deferred += 1
                reap(s.ours(_descendants()) + s._seen)
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
