"""One FMU instance in this process: fmpy's FMU2Slave, with typed batch access and clear errors.

The master talks to every FMU through the same four calls (``set``, ``do_step``, ``get``, ``terminate``), so an FMU
running in a worker process (:mod:`fishfmu.fmu.worker`) can stand in for this one.  Every failure of the FMU (a status
of error, fatal or discard from any call) is raised as :class:`plant.errors.SimulationError` naming the FMU, the call,
the status and the time. A binary that cannot be loaded (wrong platform, missing libraries) is bad input
(:class:`plant.errors.InputError` naming the file).  After a status of fatal, no further call is made to the FMU
(FMI 2.0: its state is undefined), not even terminate or freeInstance.

**The FMU's log.** Every instance gets a logger callback that keeps the last :data:`LOG_LINES` messages (nothing is
printed); when a call fails, the last message of status warning, error or fatal that the FMU logged during that call
is appended to the error, on one line and at most :data:`LOG_MESSAGE_CHARS` characters: ``FMU 'drive_c1': setReal
returned error: "fmi2SetReal: 'speed_setpoint' = 9 is outside its range [-2, 2]"``.

**Values.** ``get`` gives Real as float, Integer and Enumeration as int, Boolean as bool and String as str (fmpy gives
C ints and UTF-8 bytes); ``set`` takes the same.

**Events inside a step (FMI 3.0).** An FMU whose modelDescription declares ``hasEventMode`` is instantiated with
event mode used (and early return allowed where it declares ``mightReturnEarlyFromDoStep``): ``do_step`` from t to
t + dt then steps it to its events one by one: where doStep returns early at an event (``lastSuccessfulTime``) or asks
for event handling, the FMU enters event mode, its discrete states are updated until none needs another update, and
it goes back to step mode and on to t + dt; a time event it announces (``nextEventTime``) ends a doStep there even
without early return, and so does the tick of a periodic input clock (:mod:`fishfmu.fmu.clocks`: the clock is set
active in that event mode).  The times the FMU was in event mode are kept in ``event_times_s``.  An FMU without event mode is
stepped as before: one doStep per call.  Its outputs are read by the master at t + dt, so another component sees a
value set at an event from the end of that step on (see :mod:`fishfmu.cosim.master`).

**The library loaded** is ``binaries/linux64/<modelIdentifier>.so`` inside the unpacked archive, checked by
:func:`fishfmu.fmu.archive.library_path` right before loading and passed to fmpy by its full path.
"""

from __future__ import annotations

import itertools
import os
import re
from collections import deque
from collections.abc import Iterable, Mapping
from ctypes import byref, c_void_p
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fmpy.fmi2 import (FMU2Slave, calloc, fmi2Boolean, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Integer, fmi2Real, fmi2ValueReference, free)
from fmpy.fmi3 import FMU3Slave
from fmpy.logging import addLoggerProxy

from plant.errors import InputError, SimulationError
from plant.validation import suggest

from fishfmu.fmu.archive import DescribedFmu, FmuVariable, OpenedFmu, library_path
from fishfmu.fmu.clocks import PeriodicClocks, clock_attributes

FMI2_STATUS = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
SETTABLE_BEFORE_INIT = ("parameter", "input")
LOG_LINES = 20
"""Log messages kept per FMU instance (the newest)."""
MAX_EVENTS_PER_STEP = 10000
"""Events one ``do_step`` handles at most: an FMU with more has events without end (a Zeno ball) and is stopped."""
EVENT_TIMES_KEPT = 10000
"""Event times kept per instance (the newest)."""
LOG_MESSAGE_CHARS = 300
"""Longest FMU log message quoted in an error (longer ones are cut, ending in ...)."""
_WHITESPACE = re.compile(r"\s+")


def one_line(text: str, limit: int = LOG_MESSAGE_CHARS) -> str:
    """``text`` with every run of whitespace (newlines included) as one space, cut to ``limit`` characters.

    >>> one_line("setpoint 9 m/s\\n  out of range")
    'setpoint 9 m/s out of range'
    >>> one_line("x" * 10, limit=6)
    'xxx...'
    """
    text = _WHITESPACE.sub(" ", text).strip()
    return text if len(text) <= limit else text[:limit - 3] + "..."


_LOGS: dict[int, "FmuLog"] = {}
"""The log of each live instance in this process, by the componentEnvironment its FMU passes back.

fmpy's native logger proxy (which formats the FMU's printf-style messages) keeps one Python
logger for the whole process, so every instance has the same logger, :func:`_dispatch_log_message`,
and a componentEnvironment of its own that says whose message it is."""
_LOG_KEYS = itertools.count(1)
_LOGGER: Any = None


def _dispatch_log_message(env: int | None, instance: bytes | None, status: int, category: bytes | None,
                          message: bytes | None) -> None:
    try:
        log = _LOGS.get(env or 0)
        if log is not None:
            log.add(status, category, message)
    except Exception:  # an exception must not cross into the FMU's C code
        pass


class FmuLog:
    """The newest log messages of one FMU instance: (sequence number, status, category, message)."""

    def __init__(self, max_lines: int = LOG_LINES) -> None:
        self.lines: deque[tuple[int, int, str, str]] = deque(maxlen=max_lines)
        self.count = 0

    def add(self, status: int, category: bytes | str | None, message: bytes | str | None) -> None:
        def text(b: bytes | str | None) -> str:
            return b.decode("utf-8", "replace") if isinstance(b, bytes) else (b or "")
        self.count += 1
        self.lines.append((self.count, int(status), text(category), text(message)))

    def last_problem(self, since: int = 0) -> str | None:
        """The last message of status warning or worse logged after message number ``since``
        (errors and fatal ones first), as one line; None if there is none."""
        recent = [line for line in self.lines if line[0] > since and line[1] >= 1 and line[3].strip()]
        if not recent:
            return None
        worst = [line for line in recent if line[1] >= 3] or recent
        return one_line(worst[-1][3])


def settable_before_init(var: FmuVariable) -> bool:
    """Whether FMI lets an importer give the variable a start value: a parameter or an input, or any variable
    (a state, an output) declared with initial = exact or approx; never a constant (FMI 2.0 section 4.2.4)."""
    if var.variability == "constant":
        return False
    return var.causality in SETTABLE_BEFORE_INIT or var.initial in ("exact", "approx")


def check_parameters(name: str, fmu: DescribedFmu, parameters: Mapping[str, Any],
                     scenario_file: str | Path | None = None, where: str | None = None) -> None:
    """Every parameter a scenario sets must exist, be a parameter (or input start value) and fit its type.

    The error names ``scenario_file`` and the key ``<where>.<parameter>`` (e.g. ``fmu[0].parameters``)
    when given, else the FMU file and ``fmu.<name>.parameters``.
    """
    try:
        _check_parameters(name, fmu, parameters)
    except InputError as exc:
        if scenario_file is None:
            raise
        key = (exc.where or "").rpartition(".parameters")[2]
        raise InputError(exc.message, file=scenario_file, where=f"{where or 'fmu'}.parameters{key}") from None


def _check_parameters(name: str, fmu: DescribedFmu, parameters: Mapping[str, Any]) -> None:
    for key, value in parameters.items():
        var = fmu.variables.get(key)
        if var is None:
            raise InputError(f"FMU '{name}' has no variable '{key}'{suggest(key, fmu.variables)}", file=fmu.path,
                             where=f"fmu.{name}.parameters.{key}")
        if not settable_before_init(var):
            why = ("a constant" if var.variability == "constant" else
                   f"an {var.causality} computed by the FMU (initial = {var.initial or 'calculated'})")
            raise InputError(f"'{key}' of FMU '{name}' is {why}: FMI lets no start value be given to it",
                             file=fmu.path, where=f"fmu.{name}.parameters.{key}")
        ok = {"Real": isinstance(value, (int, float)) and not isinstance(value, bool),
              "Integer": isinstance(value, int) and not isinstance(value, bool),
              "Enumeration": isinstance(value, int) and not isinstance(value, bool),
              "Boolean": isinstance(value, bool),
              "String": isinstance(value, str)}.get(var.type, False)
        if not ok:
            raise InputError(f"'{key}' of FMU '{name}' is {var.type}; got {value!r}",
                             file=fmu.path, where=f"fmu.{name}.parameters.{key}")


def _as(kind: str, value: Any) -> Any:
    """A value as the FMU's setter takes it."""
    if kind == "Real":
        return float(value)
    if kind == "Integer":
        return int(value)
    if kind == "Boolean":
        return bool(value)
    if kind == "String":
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
    return value  # Binary: bytes


def _from(kind: str, value: Any) -> Any:
    """A value as the FMU's getter gave it, as fishfmu passes it (fmpy gives C ints and UTF-8 bytes)."""
    if kind == "Boolean":
        return bool(value)
    if kind == "String":
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else ("" if value is None else str(value))
    if kind == "Integer":
        return int(value)
    if kind == "Real":
        return float(value)
    return value


_FMI2_C_TYPES = {"Real": fmi2Real, "Integer": fmi2Integer, "Boolean": fmi2Boolean}
"""FMI 2 types handed to fmpy's C functions (``fmi2SetReal``, ...) with the value references made once: fmpy's setReal
and getReal build them on every call, about half the FMUs' Python time a step."""


@dataclass(frozen=True)
class _Batch:
    """The variables of one FMI get or set call; for FMI 2's numbers and booleans also the value references' C array,
    the values' array type and fmpy's C functions that take them (None: fmpy's own setter and getter)."""

    call: str
    kind: str
    names: tuple[str, ...]
    vrs: list[int]
    c_vrs: Any = None
    c_values: Any = None
    set_c: Any = None
    get_c: Any = None


class InProcessFmu:
    """An instantiated, initialised FMI 2.0 or 3.0 co-simulation FMU in this process (``run.fmu_process =
    "in-process"``; :class:`fishfmu.fmu.worker.WorkerFmu` is the same in a worker process); ``set``/``get`` take
    variable names."""

    def __init__(self, name: str, fmu: OpenedFmu, parameters: Mapping[str, Any], start_time_s: float = 0.0) -> None:
        check_parameters(name, fmu, parameters)
        self.name = name
        self.variables = fmu.variables
        self._batch_cache: dict[tuple[str, ...], list[_Batch]] = {}
        md = fmu.model_description
        self._time = start_time_s
        self._fatal = False
        self.log = FmuLog()
        binary = library_path(fmu)  # inside the unpacked archive, checked right before loading
        self._fmi3 = md.fmiVersion.startswith("3")
        cs = md.coSimulation
        self.event_mode = self._fmi3 and bool(getattr(cs, "hasEventMode", False))
        self._early_return = self.event_mode and bool(getattr(cs, "mightReturnEarlyFromDoStep", False))
        self.event_times_s: deque[float] = deque(maxlen=EVENT_TIMES_KEPT)
        self._next_event_s: float | None = None
        clocks = clock_attributes(fmu.unzip_dir) if self.event_mode and any(
            v.type == "Clock" for v in fmu.variables.values()) else {}
        self._clocks = PeriodicClocks.of(clocks, start_time_s) if clocks else None  # checked when the FMU was opened
        cwd = os.getcwd()
        try:
            if self._fmi3:  # fmpy joins the same path (binaries/<platform tuple>/<modelIdentifier>.so) itself
                self._slave = FMU3Slave(guid=md.instantiationToken, unzipDirectory=str(fmu.unzip_dir),
                                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
            else:
                self._slave = FMU2Slave(guid=md.guid, unzipDirectory=str(fmu.unzip_dir),
                                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name,
                                        libraryPath=str(binary))
        except Exception as exc:  # fmpy: "Failed to load shared library ..." (dlopen's reason) or a missing function
            reason = str(exc)
            for root in {str(Path(fmu.unzip_dir).resolve()), str(fmu.unzip_dir)}:
                reason = reason.replace(root + os.sep, "")
            reason = one_line(reason, 2 * LOG_MESSAGE_CHARS)
            raise InputError(f"FMU '{name}': its binary cannot be loaded on this machine: {reason}",
                             file=fmu.path) from None
        finally:
            os.chdir(cwd)  # fmpy changes into the binary's folder to load it and stays there if that fails
        try:
            if self._fmi3:
                self._log_key = 0
                # fmpy keeps the C callback alive on the slave; messages go to this instance's log
                self._call("instantiate", self._slave.instantiate, loggingOn=False, eventModeUsed=self.event_mode,
                           earlyReturnAllowed=self._early_return,
                           logMessage=lambda env, status, category, message: self.log.add(status, category, message))
            else:
                self._callbacks = self._logging_callbacks()  # kept alive as long as the instance
                self._call("instantiate", self._slave.instantiate, loggingOn=False, callbacks=self._callbacks)
        except BaseException:
            _LOGS.pop(getattr(self, "_log_key", 0), None)
            raise
        self._instantiated = True
        try:
            if not self._fmi3:
                self._call("setupExperiment", self._slave.setupExperiment, startTime=start_time_s)
            self.set(parameters)  # start values: before initialisation, where FMI allows every one (approx too)
            self._call("enterInitializationMode", self._slave.enterInitializationMode,
                       **({"startTime": start_time_s} if self._fmi3 else {}))
            self._call("exitInitializationMode", self._slave.exitInitializationMode)
            if self.event_mode:  # FMI 3.0: with event mode used the FMU leaves initialisation in event mode
                self._tick_clocks(start_time_s)
                self._update_discrete_states()
                self._call("enterStepMode", self._slave.enterStepMode)
        except BaseException:
            self.terminate()  # nobody else holds this instance yet
            raise

    def _logging_callbacks(self) -> Any:
        """fmpy's callback functions whose logger keeps this instance's messages in ``self.log``."""
        global _LOGGER
        if _LOGGER is None:
            _LOGGER = fmi2CallbackLoggerTYPE(_dispatch_log_message)
        self._log_key = next(_LOG_KEYS)
        _LOGS[self._log_key] = self.log
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = _LOGGER
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        callbacks.componentEnvironment = c_void_p(self._log_key)
        try:  # fmpy's native proxy formats the FMU's printf-style message before it reaches Python
            addLoggerProxy(byref(callbacks))
        except Exception:  # no proxy: messages with format arguments arrive unformatted
            pass
        return callbacks

    def _call(self, what: str, fn, *args: Any, **kwargs: Any) -> Any:
        since = self.log.count
        try:
            return fn(*args, **kwargs)
        except Exception as exc:  # fmpy raises FMICallException (with .status) or OSError from the library
            status = getattr(exc, "status", None)
            if status == 4:
                self._fatal = True
            text = FMI2_STATUS.get(status, str(status)) if status is not None else type(exc).__name__
            detail = "" if status is not None else f" ({one_line(str(exc))})"
            said = self.log.last_problem(since)
            if said:
                detail += f': "{said}"'
            raise SimulationError(f"FMU '{self.name}': {what} returned {text}{detail}", self._time) from None

    def _batches(self, names: Iterable[str]) -> list[_Batch]:
        """The names grouped into FMI calls by the call's type (Real, Float64, ...) and the kind of value; made once."""
        key = tuple(names)
        cached = self._batch_cache.get(key)
        if cached is not None:
            return cached
        by_type: dict[tuple[str, str], list[tuple[str, int]]] = {}
        for n in key:
            v = self.variables[n]
            kind = "Integer" if v.type == "Enumeration" else v.type
            call = (("Int64" if v.fmi_type == "Enumeration" else v.fmi_type) if self._fmi3 and v.fmi_type
                    else kind)
            by_type.setdefault((call, kind), []).append((n, v.value_reference))
        batches = []
        for (call, kind), refs in by_type.items():
            vrs = [vr for _, vr in refs]
            c_type = None if self._fmi3 else _FMI2_C_TYPES.get(call)
            c = ((fmi2ValueReference * len(vrs))(*vrs), c_type * len(vrs), getattr(self._slave, f"fmi2Set{call}"),
                 getattr(self._slave, f"fmi2Get{call}")) if c_type is not None else ()
            batches.append(_Batch(call, kind, tuple(n for n, _ in refs), vrs, *c))
        self._batch_cache[key] = batches
        return batches

    def set(self, values: Mapping[str, Any]) -> None:
        for b in self._batches(values):
            converted = [_as(b.kind, values[n]) for n in b.names]
            if b.c_vrs is None:
                self._call(f"set{b.call}", getattr(self._slave, f"set{b.call}"), b.vrs, converted)
            else:
                self._call(f"set{b.call}", b.set_c, self._slave.component, b.c_vrs, len(b.vrs), b.c_values(*converted))

    def get(self, names: Iterable[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for b in self._batches(names):
            if b.c_vrs is None:
                vals = self._call(f"get{b.call}", getattr(self._slave, f"get{b.call}"), b.vrs)
            else:
                vals = b.c_values()
                self._call(f"get{b.call}", b.get_c, self._slave.component, b.c_vrs, len(b.vrs), vals)
            out.update({n: _from(b.kind, v) for n, v in zip(b.names, vals)})
        return out

    def do_step(self, t_s: float, dt_s: float) -> None:
        if self.event_mode:
            self._step_through_events(t_s, t_s + dt_s)
            return
        self._time = t_s
        result = self._call("doStep", self._slave.doStep, currentCommunicationPoint=t_s, communicationStepSize=dt_s)
        if self._fmi3 and result is not None and result[1]:  # terminateSimulation
            self._ended(t_s + dt_s)
        self._time = t_s + dt_s

    def _ended(self, t_s: float) -> None:
        said = self.log.last_problem()
        raise SimulationError(f"FMU '{self.name}': doStep asked to end the simulation"
                              + (f': "{said}"' if said else ""), t_s)

    def _step_through_events(self, t_s: float, end_s: float) -> None:
        """From t_s to end_s, each event handled at its time (see the module's docstring)."""
        now = t_s
        for _ in range(MAX_EVENTS_PER_STEP):
            self._time = now
            if self._clock_due(now):  # a tick at the step's start (or rounded just before it)
                self._event(now)
            stop = end_s
            if self._next_event_s is not None and now < self._next_event_s < end_s:
                stop = self._next_event_s  # a time event the FMU announced: step to it
            tick = self._clocks.next_tick_s() if self._clocks is not None else None
            if tick is not None and now < tick < stop:
                stop = tick  # a periodic clock ticks: step to it
            needed, terminate, early, last = self._call("doStep", self._slave.doStep, currentCommunicationPoint=now,
                                                        communicationStepSize=stop - now)
            if terminate:
                self._ended(last if early else stop)
            if early and not now <= last <= stop:
                raise SimulationError(f"FMU '{self.name}': doStep returned early at t = {last}, outside the step "
                                      f"[{now}, {stop}]", now)
            now = self._time = last if early else stop
            if needed or self._clock_due(now):
                self._event(now)
            if now >= end_s:
                return
        raise SimulationError(f"FMU '{self.name}': more than {MAX_EVENTS_PER_STEP} events in one step from "
                              f"t = {t_s} s (events without end)", now)

    def _clock_due(self, t_s: float) -> bool:
        return self._clocks is not None and self._clocks.next_tick_s() <= t_s

    def _event(self, t_s: float) -> None:
        """Event mode at ``t_s``: the clocks that tick then activated, the discrete states updated, back to step mode."""
        self._call("enterEventMode", self._slave.enterEventMode)
        self._tick_clocks(t_s)
        self._update_discrete_states()
        self._call("enterStepMode", self._slave.enterStepMode)
        self.event_times_s.append(t_s)

    def _tick_clocks(self, t_s: float) -> None:
        """In event mode: activate the periodic clocks that tick at ``t_s`` (:mod:`fishfmu.fmu.clocks`)."""
        due = self._clocks.due(t_s) if self._clocks is not None else []
        if due:
            self._call("setClock", self._slave.setClock, due, [True] * len(due))

    def _update_discrete_states(self) -> None:
        """Event mode: update the discrete states until the FMU needs no further update (FMI 3.0's event iteration)."""
        for _ in range(MAX_EVENTS_PER_STEP):
            again, terminate, _, _, defined, next_s = self._call("updateDiscreteStates",
                                                                 self._slave.updateDiscreteStates)
            if terminate:
                self._ended(self._time)
            self._next_event_s = next_s if defined else None
            if not again:
                return
        raise SimulationError(f"FMU '{self.name}': its discrete states still need updating after "
                              f"{MAX_EVENTS_PER_STEP} updates", self._time)

    def terminate(self) -> None:
        """End and free the instance; safe to call twice and after a failure."""
        if not getattr(self, "_instantiated", False):
            _LOGS.pop(getattr(self, "_log_key", 0), None)
            return
        self._instantiated = False
        if self._fatal:
            _LOGS.pop(self._log_key, None)
            return  # FMI 2.0: after fmi2Fatal no function of the FMU may be called
        try:
            self._slave.terminate()
        except Exception:
            pass
        try:
            self._slave.freeInstance()
        except Exception:
            pass
        _LOGS.pop(self._log_key, None)
