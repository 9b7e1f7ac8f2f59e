"""Run one FMU through fmpy's FMU2Slave with named variables (for the FMU tests)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import ModelDescription

Value = float | int | bool


def start_values(unzip_dir: Path) -> dict[str, float]:
    """Start values of the parameters as written in the modelDescription (the FMU's defaults)."""
    md = read_model_description(str(unzip_dir))
    return {v.name: float(v.start) if v.type == "Real" else v.start
            for v in md.modelVariables if v.start is not None}


@dataclass
class Slave:
    """An instantiated, initialized co-simulation FMU addressed by variable names."""

    fmu: FMU2Slave
    md: ModelDescription
    time_s: float = 0.0
    log: list[str] = field(default_factory=list)
    callbacks: object = None  # the ctypes callbacks must live as long as the instance

    def _by_type(self, names: list[str]) -> dict[str, list]:
        variables = {v.name: v for v in self.md.modelVariables}
        groups: dict[str, list] = {}
        for name in names:
            groups.setdefault(variables[name].type, []).append(variables[name])
        return groups

    def set(self, **values: Value) -> None:
        for type_, variables in self._by_type(list(values)).items():
            refs = [v.valueReference for v in variables]
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger, "Boolean": self.fmu.setBoolean}[type_]
            setter(refs, [values[v.name] for v in variables])

    def get(self, *names: str) -> dict[str, Value]:
        out: dict[str, Value] = {}
        for type_, variables in self._by_type(list(names)).items():
            getter = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger, "Boolean": self.fmu.getBoolean}[type_]
            out.update(zip([v.name for v in variables], getter([v.valueReference for v in variables])))
        return {name: out[name] for name in names}  # in the order asked for

    def value(self, name: str) -> Value:
        return self.get(name)[name]

    def step(self, dt_s: float) -> None:
        self.fmu.doStep(self.time_s, dt_s)
        self.time_s += dt_s

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def start_slave(unzip_dir: Path, parameters: dict[str, Value] | None = None, *,
                inputs: dict[str, Value] | None = None, start_time_s: float = 0.0,
                log: list[str] | None = None) -> Slave:
    """Instantiate, set parameters and inputs, initialize; log messages go to ``log`` (``slave.log``).

    If a call fails the instance is freed and the fmpy exception raised (the log keeps the reason).
    """
    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2CallbackAllocateMemoryTYPE
    from fmpy.fmi2 import fmi2CallbackFreeMemoryTYPE, calloc, free
    md = read_model_description(str(unzip_dir))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip_dir),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="test")
    slave = Slave(fmu, md, start_time_s, log if log is not None else [])

    def logger(_env, _name, _status, _category, message):  # noqa: ANN001 (ctypes callback)
        slave.log.append(message.decode())

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    slave.callbacks = callbacks
    fmu.instantiate(callbacks=callbacks)
    try:
        fmu.setupExperiment(startTime=start_time_s)
        slave.set(**(parameters or {}))
        slave.set(**(inputs or {}))
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
    except Exception:
        fmu.freeInstance()
        raise
    return slave


def run_script(slave: Slave, script: list[tuple[float, dict]], until_s: float, dt_s: float,
               *names: str) -> dict[str, np.ndarray]:
    """Apply each (time, inputs) of the script when its time comes; record outputs after every step."""
    pending = sorted(script, key=lambda row: row[0])
    rows = []
    for _ in range(round(until_s / dt_s)):
        while pending and pending[0][0] <= slave.time_s + 1e-9:
            slave.set(**pending.pop(0)[1])
        slave.step(dt_s)
        rows.append([slave.time_s, *slave.get(*names).values()])
    table = np.array(rows, dtype=float)
    return {"t": table[:, 0], **{name: table[:, k + 1] for k, name in enumerate(names)}}
