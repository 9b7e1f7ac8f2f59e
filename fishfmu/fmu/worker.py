"""One FMU instance in a worker process of its own, so that an FMU that crashes or hangs cannot take
the run down (``run.fmu_process = "worker"`` in a scenario).

:class:`WorkerFmu` stands in for :class:`fishfmu.fmu.instance.InProcessFmu`: the same calls
(``set``, ``do_step``, ``get``, ``terminate``) and the same errors.  The worker is a fresh
interpreter (``python -m fishfmu.fmu.worker FD``, not a fork: the FMU's library is loaded only
there) that runs an ``InProcessFmu`` and answers over a socket pair, one pickled message per call.

- ``set`` and ``do_step`` are collected and sent together with the ``get`` that the master calls
  after every step of an FMU: one message there and one back per FMU and step (one wake-up of the
  worker).  Errors of ``set`` or ``do_step`` come back with the time and the call they belong to,
  as in-process.
- Each call has its time limit: ``timeout_s`` (``run.fmu_step_timeout_s``) for the calls of a
  step, :data:`SETUP_TIMEOUT_S` (or more) for starting the worker and instantiating.  A call that
  takes longer is a hang: the worker is killed and the run fails naming the FMU, the call and the
  time.  A worker that dies (a segmentation fault, ``abort()``, ``exit()`` inside the FMU) is named
  with the signal or exit code.
- Values and errors come back as in-process: Booleans as bool, Strings as str, and an FMU's
  failure with the message it logged (built in the worker by ``InProcessFmu``).
- The worker runs in a session of its own and ignores SIGINT, so Ctrl-C in a terminal reaches only
  the orchestrator (which stops the run where it decides and ends its workers); a worker ends when
  its socket closes, so it never outlives the orchestrator, even one killed outright.

What it costs per step is measured by ``python -m fishfmu.bench.fmu_worker`` (see docs/performance.md).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections import deque
from collections.abc import Iterable, Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from plant.errors import InputError, SimulationError

from fishfmu.fmu.archive import OpenedFmu
from fishfmu.fmu.instance import InProcessFmu, check_parameters, one_line

SETUP_TIMEOUT_S = 60.0
"""Longest wait for a worker to start and instantiate its FMU (a cold interpreter on a busy machine)."""
TERMINATE_TIMEOUT_S = 5.0


def _signal_name(returncode: int | None) -> str:
    if returncode is None:
        return "no exit status"
    if returncode < 0:
        try:
            return f"killed by signal {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exit code {returncode}"


class WorkerFmu:
    """An instantiated, initialised FMU running in its own process; ``set``/``get`` take variable names."""

    def __init__(self, name: str, fmu: OpenedFmu, parameters: Mapping[str, Any], timeout_s: float = 10.0,
                 start_time_s: float = 0.0, setup_timeout_s: float = SETUP_TIMEOUT_S) -> None:
        check_parameters(name, fmu, parameters)  # bad input is found here, before a process is started
        self.name = name
        self.variables = fmu.variables
        self.timeout_s = float(timeout_s)
        self._time = start_time_s
        self._pending: deque[tuple[str, float, float]] = deque()  # (call, time, timeout) awaiting an answer
        self._batch: list[tuple] = []  # set and do_step requests not sent yet
        self._batch_call: tuple[str, float] | None = None  # the call a hang of the batch is blamed on
        self._closed = False
        self.round_trips = 0
        ours, theirs = socket.socketpair()
        env = dict(os.environ)
        package_root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = os.pathsep.join([package_root, *filter(None, [env.get("PYTHONPATH")])])
        try:
            self._proc = subprocess.Popen([sys.executable, "-m", "fishfmu.fmu.worker", str(theirs.fileno())],
                                          pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=env,
                                          start_new_session=True)
        except OSError as exc:
            ours.close()
            raise SimulationError(f"FMU '{name}': could not start its worker process: {exc}", start_time_s) from None
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._send(("open", name, fmu, dict(parameters), start_time_s), "instantiate",
                   max(setup_timeout_s, self.timeout_s))

    # ---- the four calls of the master ---------------------------------------------------------
    def set(self, values: Mapping[str, Any]) -> None:
        if values:
            self._batch.append(("set", dict(values)))
            self._batch_call = self._batch_call or ("set", self._time)

    def do_step(self, t_s: float, dt_s: float) -> None:
        self._time = t_s
        self._batch.append(("do_step", t_s, dt_s))
        self._batch_call = ("doStep", t_s)
        self._time = t_s + dt_s

    def get(self, names: Iterable[str]) -> dict[str, Any]:
        self._batch.append(("get", list(names)))
        call, t = self._batch_call or ("get", self._time)
        batch, self._batch, self._batch_call = self._batch, [], None
        self._send(("batch", batch), call, self.timeout_s, t)
        return self._collect()

    def terminate(self) -> None:
        """End the instance and its worker; safe to call twice and after a failure."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._proc.poll() is None:
                try:
                    self._pending.clear()
                    self._batch.clear()
                    self._conn.send(("terminate",))
                    deadline = time.monotonic() + TERMINATE_TIMEOUT_S
                    while time.monotonic() < deadline and self._conn.poll(max(0.0, deadline - time.monotonic())):
                        if self._conn.recv()[0] == "terminated":
                            break
                except (OSError, EOFError):
                    pass
                try:
                    self._proc.wait(TERMINATE_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    self._proc.kill()
                    self._proc.wait()
        finally:
            self._conn.close()

    def __del__(self) -> None:  # a worker must not outlive its owner, whatever happened
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            proc.kill()

    # ---- messages -----------------------------------------------------------------------------
    def _send(self, message: tuple, call: str, timeout_s: float, t: float | None = None) -> None:
        t = self._time if t is None else t
        if self._closed:
            raise SimulationError(f"FMU '{self.name}': {call} after its worker was stopped", t)
        try:
            self._conn.send(message)
        except (OSError, EOFError):
            self._died(call, t)
        self._pending.append((call, t, timeout_s))

    def _collect(self) -> Any:
        """Answers of everything pending, in order; the first error is raised after all are read."""
        error: Exception | None = None
        result: Any = None
        self.round_trips += 1
        while self._pending:
            call, t, timeout = self._pending[0]
            if not self._conn.poll(timeout):
                self._hung(call, t, timeout)
            try:
                reply = self._conn.recv()
            except (EOFError, OSError):
                self._died(call, t)
            self._pending.popleft()
            kind = reply[0]
            if kind == "ok":
                result = reply[1]
            elif kind == "input_error" and error is None:
                error = InputError(reply[1], file=reply[2], where=reply[3])
            elif kind == "simulation_error" and error is None:
                error = SimulationError(reply[1], t if reply[2] is None else reply[2])
        if error is not None:
            raise error
        return result

    def _stop(self) -> None:
        self._closed = True
        self._pending.clear()
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        self._conn.close()

    def _hung(self, call: str, t: float, timeout: float) -> None:
        self._stop()
        raise SimulationError(f"FMU '{self.name}': {call} did not return within {timeout:g} s (hung); "
                              "its worker process was killed", t)

    def _died(self, call: str, t: float) -> None:
        try:
            self._proc.wait(2.0)
        except subprocess.TimeoutExpired:
            pass
        how = _signal_name(self._proc.poll())
        self._stop()
        raise SimulationError(f"FMU '{self.name}': its worker process died during {call} ({how})", t)


# ---------------------------------------------------------------------------------------- worker

def serve(conn: Connection) -> None:
    """The worker's loop: one InProcessFmu, one answer per message, until terminate or end of input."""
    instance: InProcessFmu | None = None
    name = "?"
    failed = False
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            break
        op = message[0]
        if op == "terminate":
            if instance is not None:
                instance.terminate()
            conn.send(("terminated",))
            break
        if failed:
            conn.send(("skipped",))  # after an error only terminate is served
            continue
        try:
            result = None
            if op == "open":
                _, name, fmu, parameters, start_time_s = message
                instance = InProcessFmu(name, fmu, parameters, start_time_s)
            elif instance is None:
                raise SimulationError(f"FMU '{name}': {op} before the instance was created")
            elif op == "batch":
                for request in message[1]:
                    result = _call(instance, name, request)
            else:
                result = _call(instance, name, message)
            conn.send(("ok", result))
        except InputError as exc:
            failed = True
            conn.send(("input_error", exc.message, None if exc.file is None else str(exc.file), exc.where))
        except SimulationError as exc:
            failed = True
            conn.send(("simulation_error", exc.message, exc.time_s))
        except Exception as exc:  # anything else the FMU's wrapper raised: still this FMU's failure
            failed = True
            conn.send(("simulation_error", f"FMU '{name}': {op} failed: {type(exc).__name__}: {one_line(str(exc))}",
                       None))


def _call(instance, name: str, request: tuple) -> Any:
    op = request[0]
    if op == "set":
        return instance.set(request[1])
    if op == "do_step":
        return instance.do_step(request[1], request[2])
    if op == "get":
        return instance.get(request[1])
    raise SimulationError(f"FMU '{name}': unknown request {op!r} to its worker")


def main(argv: list[str]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the orchestrator's to handle
    conn = Connection(int(argv[0]))
    try:
        serve(conn)
    finally:
        conn.close()


if __name__ == "__main__":
    main(sys.argv[1:])
