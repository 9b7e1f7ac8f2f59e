"""The served line: the co-simulation of a checked scenario stepped behind an OPC UA server.

The line is stepped in one worker thread, never in the server's event loop: while it steps, the server answers
reads, writes, other clients and ``stop()``; a ``step(n)`` publishes its progress every 0.1 s of wall time and
ends early, between two communication steps, on ``stop()``, ``reset()`` or a signal.  ``reset()`` starts the run
over (and forgets what clients wrote in the run it discards).  What a client wrote to an external input is used
from the next communication step on, as a PLC's outputs are on its next scan.

Two ways to advance: **lockstep** (the line moves only when a client calls ``step(n)``) and **real time**
(:mod:`fishfmu.serve.pacing`: step k is due at ``start + k dt / FACTOR``; the wait for it ends at once on
``stop()``, ``reset()`` or a signal).  The run ends where ``fishfmu run`` ends it (its duration, or once every
fish has left with ``stop_when_clear``), or when a client calls ``stop()``, or on a signal (within a
communication step and 0.05 s); :meth:`LineServer.run` then gives it as a :class:`~fishfmu.cosim.results.RunResult`,
which the command writes like any run.

What the servers show (OPC UA with its status nodes, Modbus, the live view) is the line's step observer,
:class:`~fishfmu.serve.publication.Publication`, attached to each run the line builds beside the observers every way
of stepping attaches; it is published after each batch of steps (why: :mod:`fishfmu.serve.publication`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import os
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from plant.errors import InputError, SimulationError
from plant.contract.kpis import KPI_KEYS
from plant.sim.observers import StepObserver
from plant.sim.plant import ON_LINE

from fishfmu.cosim.build import BuildFailed, CheckedScenario, build, scenario_fish
from fishfmu.cosim.master import CoSimulation
from fishfmu.cosim.results import RunResult
from fishfmu.cosim.runner import collect, run_end
from fishfmu.cosim.stop import StopRequest
from fishfmu.scenario.wiring import signal_names
from fishfmu.serve.access import Account, LineUsers, hash_password, read_users
from fishfmu.serve.address_space import NAMESPACE, AddressSpace, shown_values
from fishfmu.serve.model import KPIS, served_signals
from fishfmu.serve.options import (DEFAULT_ENDPOINT, PASSWORD_ENV, Certificates, endpoint_problem,
                                   modbus_problem, realtime_problem)
from fishfmu.serve.pacing import Pacing
from fishfmu.serve.publication import Publication
from fishfmu.serve.server import make_server, start_server
from fishfmu.serve.status import (DEFAULT_GRACE_S, FINISHED, PAUSED, RUNNING, STOPPED, WAITING, InvalidState,
                                  RunClock, grace_problem)

POLL_S = 0.05
"""How often the event loop looks for a signal (a Python signal handler cannot wake it) and a due step."""
PUBLISH_EVERY_S = 0.1
"""Wall time between two publications of a long step(n)'s progress."""
FINE_WAIT_S = 0.0015
"""The end of the wait for a step, slept on the OS's timer with the event loop held: the loop's epoll timeout is whole
milliseconds, rounded up (steps began 0.85 ms late at the median on the 2-core machine, 0.1 ms so)."""
AHEAD_KEEP_S = 0.0005
"""Served in real time, the wall time before the next step kept free for handing work to the worker thread and back
when the plant lays out its next rebuilds in the rest (:meth:`plant.sim.plant.Plant.build_ahead`)."""


class LineServer:
    """The co-simulation of a checked scenario behind an asyncua server (see the module docstring)."""

    def __init__(self, checked: CheckedScenario, endpoint: str = DEFAULT_ENDPOINT, allow_remote: bool = False,
                 realtime: float | None = None, user: str | None = None,
                 certificates: Certificates | None = None, wait_for_start: bool = False,
                 grace_s: float = DEFAULT_GRACE_S, users_file: Path | None = None,
                 allow_anonymous_write: bool = False, modbus: str | None = None, live: str | None = None,
                 observers: Sequence[StepObserver] = ()) -> None:
        problem = endpoint_problem(endpoint, allow_remote)
        if problem:
            raise InputError(problem, where="--endpoint")
        problem = certificates.problem() if certificates is not None else None
        if problem:
            raise InputError(problem[1], where=problem[0])
        self.certificates = certificates
        self.user = user
        if user is not None:  # one operator, no anonymous sessions
            password = os.environ.get(PASSWORD_ENV)
            if not password:
                raise InputError(f"--user {user} needs the password in the environment variable {PASSWORD_ENV}",
                                 where="--user")
            self.users = LineUsers({user: Account(user, "operator", hash_password(password))}, None)
        else:
            self.users = LineUsers(read_users(users_file) if users_file is not None else {},
                                   "operator" if allow_anonymous_write else "viewer")
        problem = realtime_problem(realtime)
        if problem:
            raise InputError(problem, where="--realtime")
        problem = grace_problem(grace_s)
        if problem:
            raise InputError(problem, where="--grace")
        self.wait_for_start, self.grace_s = wait_for_start, grace_s
        problem = modbus_problem(modbus, allow_remote) if modbus is not None else None
        if problem:
            raise InputError(problem, where="--modbus")
        self.modbus_at, self.allow_anonymous_write = modbus, allow_anonymous_write
        problem = modbus_problem(live, allow_remote, "live view") if live is not None else None
        if problem:
            raise InputError(problem, where="--live")
        self.live_at = live
        self.clock = RunClock()
        self.kpis: dict[str, Any] = {}
        """The run's KPIs once it has ended (served under fishfmu.kpis)."""
        self._announced: str | None = None
        self.checked, self.endpoint, self.realtime = checked, endpoint, realtime
        self.scenario = checked.scenario
        self.fish = scenario_fish(self.scenario)
        self.names = signal_names(checked.wiring)
        self.served = served_signals(checked, self.names)
        """Every signal in the address space: the run's signals, then the plant's outputs it does not record."""
        self.external = list(checked.wiring.external)
        self.space = AddressSpace(checked, self.served, self.external)
        self.publication = Publication(self.space, [cv.id for cv in self.scenario.line.conveyors])
        self.observers = list(observers)
        """Step observers attached to each run the line builds, after its publication (a script's own)."""
        self.written: list[dict[str, Any]] = []
        """Every change clients made to an external input in this run (since the last reset), with the simulated
        time from which it was used."""
        self.pacing = Pacing(realtime or 1.0, self.scenario.run.comm_step_s)
        self.state = RUNNING
        self.error: str | None = None
        self.resets = 0
        self.stop_requested = threading.Event()
        """A client called stop()."""
        self._interrupt = threading.Event()
        """stop(), reset() or the end of serving: a step(n) under way ends after its current step."""
        self._signal: StopRequest | None = None
        self._crash: BaseException | None = None
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fishfmu-line")
        """The one thread that builds, steps and closes the line: never two steps at once, never in the event loop."""
        self._lock: asyncio.Lock | None = None
        self._stack = contextlib.ExitStack()
        self.cosim: CoSimulation | None = None
        self._build_failed: BuildFailed | None = None
        self._restarted = False
        self.behind: str | None = None

    # ---- the whole of it ----------------------------------------------------------------------------------
    def run(self, on_ready: Any = None, stop: StopRequest | None = None) -> RunResult:
        """Build the line, serve it until its run ends, and give the run: ``ok`` when it ended at the scenario's
        end or by a client's stop(), ``partial`` by ``stop`` (a signal), ``failed`` with the error of an FMU or
        the plant.  ``on_ready(self)`` is called once clients can connect.  Raises InputError naming --endpoint
        when the server cannot listen there, and a bug in a step as itself."""
        t0 = time.perf_counter()
        self.build_line()
        if self.cosim is not None:  # else an FMU failed while the line was built: a failed run
            asyncio.run(self.serve(on_ready, stop))
        ended = self.state == FINISHED or self.stop_requested.is_set()
        status = "failed" if self.error else "ok" if ended else "partial"
        return self.result(status, time.perf_counter() - t0)

    # ---- the co-simulation (in the worker thread) --------------------------------------------------
    def build_line(self) -> None:
        """Build the co-simulation (its FMUs instantiated and initialised) before serving it; an FMU failing in
        that leaves ``cosim`` None and the state failed."""
        self._worker.submit(self._start_cosim).result()

    def _start_cosim(self) -> None:
        self._stack.close()
        self._stack = contextlib.ExitStack()
        self.cosim, self._build_failed = None, None
        try:
            # the one place the served line attaches its step observers (fishfmu.serve.publication)
            self.publication.new_run()
            self.cosim = self._stack.enter_context(build(self.checked, self.fish,
                                                         observers=[self.publication, *self.observers]))
        except BuildFailed as exc:
            self._build_failed = exc
            self.state, self.error = f"failed: {exc}", str(exc)
            return
        self.state, self.error = WAITING if self.wait_for_start else RUNNING, None
        self._end = run_end(self.scenario)

    def close(self) -> None:
        """Terminate the FMUs and free the plant (in the worker thread, after whatever it still does)."""
        with contextlib.suppress(RuntimeError):  # already shut down
            self._worker.submit(self._stack.close).result()
        self._worker.shutdown(wait=True)

    def _take_writes(self) -> None:
        """Client writes to the external inputs, applied before the next step."""
        for key, value in self.space.changed_inputs():
            self.cosim.set_external(key, value)
            self.written.append({"t_s": round(self.cosim.t_s, 9), "input": key, "value": value})

    def _step_once(self) -> bool:
        """One communication step; False when the run failed in it."""
        try:
            self.cosim.step()
        except SimulationError as exc:
            self.state, self.error = f"failed: {exc}", str(exc)
            return False
        # the run ends where `fishfmu run` ends it (one rule: its duration, or once every fish has left)
        if self._end.reached(self.cosim.steps, self.cosim.t_s, lambda: self.cosim.plant.state.status):
            self.state = FINISHED
        return True

    def _interrupted(self) -> bool:
        return self._interrupt.is_set() or (self._signal is not None and self._signal.requested)

    def _run_steps(self, n: int, budget_s: float) -> int:
        """Up to ``n`` steps with what clients wrote before each; fewer at the run's end or failure, on an
        interrupt (stop(), reset(), a signal) and after ``budget_s`` of wall time.  The steps made."""
        done, until = 0, time.monotonic() + budget_s
        try:
            while done < n and self.cosim is not None and self.state == RUNNING and not self._interrupted():
                self._take_writes()
                if not self._step_once():
                    break
                done += 1
                if time.monotonic() >= until:
                    break
        except Exception as exc:  # a bug: end serving and report it (exit 4), never step on after it
            self._crash = exc
            self.state, self.error = "failed: internal error", f"{type(exc).__name__}: {exc}"
        return done

    def _build_ahead(self, budget_s: float) -> None:
        """The time before the next step spent on the next rebuild (:meth:`plant.sim.plant.Plant.build_ahead`)."""
        if self.cosim is not None and self.state == RUNNING:
            self.cosim.plant.build_ahead(budget_s)

    async def _in_worker(self, fn: Any, *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._worker, fn, *args)

    # ---- what clients call ------------------------------------------------------------------------------
    async def step(self, n: int) -> float:
        """Lockstep: ``n`` communication steps (fewer at the end of the run, or when stop(), reset() or a signal
        comes first); the new time.  Progress is published every PUBLISH_EVERY_S while it steps."""
        async with self._lock:
            if self.state in (WAITING, PAUSED):
                raise InvalidState(self.state)
            left = n
            while left > 0 and self.state == RUNNING and not self._interrupted():
                done = await self._in_worker(self._run_steps, left, PUBLISH_EVERY_S)
                left -= done
                if done == 0 or left == 0:
                    break
                await self._publish()  # the progress of a long step, for readers
            await self._publish()
            return self.cosim.t_s if self.cosim is not None else 0.0

    async def stop(self) -> None:
        """A client's stop(): the run ends (a step(n) under way after its current step) and is written."""
        self.stop_requested.set()
        self._interrupt.set()  # a step(n) under way ends after its current step
        async with self._lock:
            if self.state in (RUNNING, WAITING, PAUSED):
                self.state = STOPPED
            await self._publish()

    async def reset(self, seed: int | None = None) -> float:
        """A client's reset(): the run starts over (with the scenario's seed, or ``seed``); what clients wrote in
        the run discarded is forgotten."""
        self._interrupt.set()
        async with self._lock:
            if seed is not None and seed != self.scenario.run.seed:
                self._reseed(seed)
            await self._in_worker(self._start_cosim)
            self.clock, self.kpis = RunClock(), {}
            self.clock.enter(self.state)
            self._interrupt.clear()
            # the run written is the one after the reset: what clients wrote before it is gone with it
            self.written.clear()
            self.pacing.clear()
            self.behind = None
            self.resets += 1
            self._restarted = True  # real time: pacing starts over from now
            await self.space.restart_inputs()
            await self._publish()
            return self.cosim.t_s if self.cosim is not None else 0.0

    def _reseed(self, seed: int) -> None:
        """The run after a reset(seed): the scenario with that seed (its batch of fish sampled from it)."""
        run = self.scenario.run.model_copy(update={"seed": seed})
        self.scenario = self.scenario.model_copy(update={"run": run})
        self.checked = dataclasses.replace(self.checked, scenario=self.scenario)
        self.fish = scenario_fish(self.scenario)

    async def start(self) -> None:
        """A client's start(): a run waiting for it (--wait-for-start) runs."""
        await self._change(WAITING, RUNNING)

    async def pause(self) -> None:
        """A client's pause(): the line stops advancing until resume()."""
        await self._change(RUNNING, PAUSED)

    async def resume(self) -> None:
        await self._change(PAUSED, RUNNING)

    async def set_speed(self, factor: float) -> None:
        """A client's set_speed(factor): real time paced to ``factor`` from the next step on."""
        async with self._lock:
            self.pacing.factor = factor
            self.realtime = factor
            self._restarted = True  # the due times start over from now at the new pace
            await self._publish()

    async def _change(self, before: str, after: str) -> None:
        async with self._lock:
            if self.state != before:
                raise InvalidState(self.state)
            self.state = after
            self._restarted = True  # real time: the due times start over from now
            await self._publish()

    async def _publish(self) -> None:
        """Show the line, its clock and its state; announce a change of state (an event) and, once the run has
        ended, its KPIs."""
        if self.state != self._announced:
            self.clock.enter(self.state)
            if self.cosim is not None and self.state == FINISHED and not self.kpis:
                res = await self._in_worker(self._result, "ok", 0.0)
                self.kpis = {f"{KPIS}.{k}": (float(v) if isinstance(v, (int, float)) and v is not None else math.nan)
                             for k, v in res.kpis.items() if k in KPI_KEYS}
        t_s = self.cosim.t_s if self.cosim is not None else 0.0
        status = {"fishfmu.lag_s": self.pacing.lag_s, "fishfmu.lag_max_s": self.pacing.lag_max_s,
                  "fishfmu.late_steps": self.pacing.late_steps,
                  "fishfmu.realtime_factor": self.realtime or 0.0,
                  "fishfmu.realtime_factor_reached": self.clock.factor_reached(t_s),
                  **(self.kpis or {f"{KPIS}.{k}": math.nan for k in KPI_KEYS})}
        await self.publication.publish(shown_values(self.cosim, self.state, self.names, self.served, status),
                                       self.cosim)
        if self.state != self._announced:
            self._announced = self.state
            await self.space.announce(self.state)

    # ---- serving --------------------------------------------------------------------------------
    def _ending(self) -> bool:
        """Serving ends: a client's stop(), a signal, a bug in a step, or the grace time after the run finished or
        failed (a PLC reads that, and the KPIs, before the server goes)."""
        return (self.stop_requested.is_set() or self._crash is not None
                or (self._signal is not None and self._signal.requested) or self.clock.grace_over(self.grace_s))

    async def serve(self, on_ready: Any = None, stop: StopRequest | None = None) -> None:
        """Serve until the run ends (real time), a client calls stop(), or ``stop.requested`` (a signal).
        Raises InputError naming --endpoint when the server cannot listen there."""
        self._signal, self._lock = stop, asyncio.Lock()
        server = await make_server(self.endpoint, self.users, self.certificates)
        if self.cosim is None and self._build_failed is None:
            await self._in_worker(self._start_cosim)
        if self.cosim is None:  # an FMU failed while the line was built: nothing to serve
            return
        await self.space.build(server, self.realtime is None, self)
        await self._publish()
        if stop is not None and stop.requested:  # a signal while starting: nothing to serve
            return
        await start_server(server, self.endpoint)
        try:
            if self.modbus_at is not None:
                await self.publication.start_modbus(self.modbus_at, self.allow_anonymous_write, self)
            if self.live_at is not None:
                await self.publication.start_live(self.live_at, self, self._lock)
            if on_ready is not None:
                on_ready(self)
            if self.realtime is None:
                while not self._ending():
                    await asyncio.sleep(POLL_S)
            else:
                await self._run_realtime()
            self._interrupt.set()
            async with self._lock:  # a step(n) under way ends after its current step
                if self.state == RUNNING and self.stop_requested.is_set():
                    self.state = STOPPED
        finally:
            await self.publication.stop()
            await server.stop()
        if self._crash is not None:
            raise self._crash

    async def _sleep_until(self, due: float) -> bool:
        """Wait for the monotonic time ``due`` (never returning before it), looking for the end of serving and a
        reset every POLL_S; False when one of them came first."""
        await asyncio.sleep(0)  # let clients in even when late
        while (left := due - time.monotonic()) > FINE_WAIT_S:
            if self._ending() or self._restarted:
                return False
            await asyncio.sleep(min(left - FINE_WAIT_S, POLL_S))
        while (left := due - time.monotonic()) > 0:  # the loop held for at most FINE_WAIT_S
            time.sleep(left)
        return True

    async def _run_realtime(self) -> None:
        dt_wall = self.pacing.step_wall_s
        start, k, warned = time.monotonic(), 0, False
        while not self._ending():
            if self._restarted:  # a reset, start(), resume() or set_speed(): due times from now at the pace set
                dt_wall = self.pacing.step_wall_s
                start, k, warned, self._restarted = time.monotonic(), 0, False, False
            if self.state != RUNNING:  # waiting, paused, or ended (for the grace time): nothing to pace
                await asyncio.sleep(POLL_S)
                continue
            due = start + k * dt_wall
            if not await self._sleep_until(due):
                continue
            now = time.monotonic()
            async with self._lock:
                if self._restarted or self._ending() or self.state != RUNNING:
                    continue
                self.pacing.record(now - due)
                await self._in_worker(self._run_steps, 1, math.inf)
                await self._publish()
                if (spare_s := start + (k + 1) * dt_wall - time.monotonic() - AHEAD_KEEP_S) > 0:
                    await self._in_worker(self._build_ahead, spare_s)
            k += 1
            late_s = self.pacing.recent_median_s()
            if not warned and late_s is not None and late_s > dt_wall:
                warned = True
                n_fish = int(np.sum(self.cosim.plant.state.status == ON_LINE))
                self.behind = (f"cannot keep up with real time x{self.realtime:g}: at t = {self.cosim.t_s:.2f} s the "
                               f"median lateness of the last 100 steps is {1e3 * late_s:.1f} ms "
                               f"({n_fish} fish in play)")
                print(self.behind, flush=True)

    # ---- the run ------------------------------------------------------------------------------------------
    def result(self, status: str, wall_s: float) -> RunResult:
        """The served run as a RunResult (collected in the worker thread, after all its steps)."""
        return self._worker.submit(self._result, status, wall_s).result()

    def _result(self, status: str, wall_s: float) -> RunResult:
        c = self.cosim
        error = self.error if self.error else (None if status == "ok" else
                                               f"stopped by a signal at t = {c.t_s:.3f} s")
        if c is None:  # an FMU failed while the line was built
            failed = self._build_failed
            res = collect(self.scenario, self.fish, failed.plant, failed.recorder, None, status, error, {}, wall_s,
                          self.names)
        else:
            res = collect(self.scenario, self.fish, c.plant, c.recorder, c, status, error, {}, wall_s)
        res.wiring = self.checked.wiring.describe()
        res.served = {"endpoint": self.endpoint, "mode": "lockstep" if self.realtime is None else "realtime",
                      "namespace": NAMESPACE, "external_inputs": self.external, "writes": self.written,
                      "resets": self.resets,
                      "ended": ("the scenario's end" if self.state == FINISHED else
                                "stop() called by a client" if self.stop_requested.is_set() else
                                self.error or "a signal"),
                      **({"pacing": self.pacing.summary()} if self.realtime is not None else {}),
                      **({"behind": self.behind} if self.behind else {})}
        return res
