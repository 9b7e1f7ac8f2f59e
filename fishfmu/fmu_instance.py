"""One FMU instance in this process: fmpy's FMU2Slave, with typed batch access and clear errors.

The master talks to every FMU through the same four calls (``set``, ``do_step``, ``get``,
``terminate``), so an FMU running in a worker process (:mod:`fishfmu.fmu_worker`) can stand in
for this one.  Every failure of the FMU (a status of error, fatal or discard from any call) is
raised as :class:`plant.errors.SimulationError` naming the FMU, the call, the status and the time.
A binary that cannot be loaded (wrong platform, missing libraries) is bad input
(:class:`plant.errors.InputError` naming the file).  After a status of fatal, no further call
is made to the FMU (FMI 2.0: its state is undefined), not even terminate or freeInstance.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from fmpy.fmi2 import FMU2Slave

from plant.errors import InputError, SimulationError

from fishfmu.fmu_files import OpenedFmu

FMI2_STATUS = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
SETTABLE_BEFORE_INIT = ("parameter", "input")


def check_parameters(name: str, fmu: OpenedFmu, parameters: Mapping[str, Any],
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


def _check_parameters(name: str, fmu: OpenedFmu, parameters: Mapping[str, Any]) -> None:
    import difflib
    for key, value in parameters.items():
        var = fmu.variables.get(key)
        if var is None:
            close = difflib.get_close_matches(key, list(fmu.variables), n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise InputError(f"FMU '{name}' has no variable '{key}'{hint}", file=fmu.path,
                             where=f"fmu.{name}.parameters.{key}")
        if var.causality not in SETTABLE_BEFORE_INIT:
            raise InputError(f"'{key}' of FMU '{name}' is an {var.causality}, not a parameter: it cannot be set",
                             file=fmu.path, where=f"fmu.{name}.parameters.{key}")
        ok = {"Real": isinstance(value, (int, float)) and not isinstance(value, bool),
              "Integer": isinstance(value, int) and not isinstance(value, bool),
              "Enumeration": isinstance(value, int) and not isinstance(value, bool),
              "Boolean": isinstance(value, bool),
              "String": isinstance(value, str)}.get(var.type, False)
        if not ok:
            raise InputError(f"'{key}' of FMU '{name}' is {var.type}; got {value!r}",
                             file=fmu.path, where=f"fmu.{name}.parameters.{key}")


class FmuInstance:
    """An instantiated, initialised FMU; ``set``/``get`` take variable names."""

    def __init__(self, name: str, fmu: OpenedFmu, parameters: Mapping[str, Any], start_time_s: float = 0.0) -> None:
        check_parameters(name, fmu, parameters)
        self.name = name
        self.variables = fmu.variables
        self._ref_cache: dict[tuple[str, ...], dict[str, list[tuple[str, int]]]] = {}
        md = fmu.model_description
        self._time = start_time_s
        self._fatal = False
        cwd = os.getcwd()
        try:
            self._slave = FMU2Slave(guid=md.guid, unzipDirectory=str(fmu.unzip_dir),
                                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        except Exception as exc:  # fmpy: "Failed to load shared library ..." (dlopen's reason) or a missing function
            reason = str(exc).replace(str(fmu.unzip_dir) + os.sep, "")
            raise InputError(f"FMU '{name}': its binary cannot be loaded on this machine: {reason}",
                             file=fmu.path) from None
        finally:
            os.chdir(cwd)  # fmpy changes into the binary's folder to load it and stays there if that fails
        self._call("instantiate", self._slave.instantiate, loggingOn=False)
        self._instantiated = True
        self._call("setupExperiment", self._slave.setupExperiment, startTime=start_time_s)
        self._call("enterInitializationMode", self._slave.enterInitializationMode)
        self.set(parameters)
        self._call("exitInitializationMode", self._slave.exitInitializationMode)

    def _call(self, what: str, fn, *args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except Exception as exc:  # fmpy raises FMICallException (with .status) or OSError from the library
            status = getattr(exc, "status", None)
            if status == 4:
                self._fatal = True
            text = FMI2_STATUS.get(status, str(status)) if status is not None else type(exc).__name__
            raise SimulationError(f"FMU '{self.name}': {what} returned {text}"
                                  + ("" if status is not None else f" ({exc})"), self._time) from None

    def _refs(self, names: Iterable[str]) -> dict[str, list[tuple[str, int]]]:
        key = tuple(names)
        cached = self._ref_cache.get(key)
        if cached is not None:
            return cached
        by_type: dict[str, list[tuple[str, int]]] = {}
        for n in key:
            v = self.variables[n]
            t = "Integer" if v.type == "Enumeration" else v.type
            by_type.setdefault(t, []).append((n, v.value_reference))
        self._ref_cache[key] = by_type
        return by_type

    def set(self, values: Mapping[str, Any]) -> None:
        for t, refs in self._refs(values).items():
            vrs = [vr for _, vr in refs]
            vals = [values[n] for n, _ in refs]
            if t == "Real":
                self._call("setReal", self._slave.setReal, vrs, [float(v) for v in vals])
            elif t == "Integer":
                self._call("setInteger", self._slave.setInteger, vrs, [int(v) for v in vals])
            elif t == "Boolean":
                self._call("setBoolean", self._slave.setBoolean, vrs, [bool(v) for v in vals])
            elif t == "String":
                self._call("setString", self._slave.setString, vrs, [str(v) for v in vals])

    def get(self, names: Iterable[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for t, refs in self._refs(names).items():
            vrs = [vr for _, vr in refs]
            getter = {"Real": self._slave.getReal, "Integer": self._slave.getInteger,
                      "Boolean": self._slave.getBoolean, "String": self._slave.getString}[t]
            vals = self._call(f"get{t}", getter, vrs)
            out.update({n: v for (n, _), v in zip(refs, vals)})
        return out

    def do_step(self, t_s: float, dt_s: float) -> None:
        self._time = t_s
        self._call("doStep", self._slave.doStep, currentCommunicationPoint=t_s, communicationStepSize=dt_s)
        self._time = t_s + dt_s

    def terminate(self) -> None:
        """End and free the instance; safe to call twice and after a failure."""
        if not getattr(self, "_instantiated", False):
            return
        self._instantiated = False
        if self._fatal:
            return  # FMI 2.0: after fmi2Fatal no function of the FMU may be called
        try:
            self._slave.terminate()
        except Exception:
            pass
        try:
            self._slave.freeInstance()
        except Exception:
            pass
