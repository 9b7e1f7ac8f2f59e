"""The co-simulation master: fixed communication step, FMUs and plant stepped in a defined order.

One base step from t to t + dt reads top to bottom (see :meth:`CoSimulation.step`):

1. apply the scenario's events due at t (override, bias or reset a variable);
2. step the FMUs in wiring order, each due one every ``step_multiple`` base steps, after setting
   its inputs from its sources (Gauss-Seidel: what they hold now; Jacobi: the start of the step);
3. set the belt speeds and device commands from their sources and step the plant; hand its published state and
   the step's inputs (the belts' setpoints among them) to the step observers (:mod:`plant.sim.observers`), the
   same a run of the plant alone and the plant FMU attach: the energy watch (:mod:`plant.sim.health`: a blow-up
   stops the run within this step), the fish counts, the recording of the run in the measured-data format, then
   any ``observers`` attached (``fishfmu serve``'s publication);
4. record every connected signal at t + dt (``signals.csv``: the master's own record of what it sent and got,
   which only a co-simulation has).

An FMU stepping every m base steps does one step of m * dt at the start of its block; as with a
one-step FMU under Gauss-Seidel, the others use its end-of-step outputs for the whole block, and
they are held until its next step.

An FMI 3.0 FMU with event mode handles its events inside its own step, each at its time
(:mod:`fishfmu.fmu.instance`); what it outputs is read here when that step ends: the plant, which takes one value per
base step, steps the base step in which the event fell with it (Gauss-Seidel) or the next one (Jacobi).

**Values between components** keep the type of their variable: Real as float, Integer as int,
Boolean as bool, String as str (decoded from UTF-8), in-process and with FMUs in worker
processes alike.  ``signals.csv`` (:meth:`CoSimulation.signal_frame`, written by pandas) holds
numbers as numbers, Booleans as ``True``/``False`` (pandas reads them back as bool) and strings as
text.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd

from plant.errors import SimulationError
from plant.sim.observers import StepInputs, StepObserver, notify, plant_observers
from plant.sim.plant import Plant
from plant.sim.ports import PlantPorts
from plant.sim.recorder import RunRecorder
from plant.sim.state import PlantOutputs

from fishfmu.scenario.schema import Event
from fishfmu.scenario.wiring import PLANT, Connection, Wiring, signal_names


STAGES = ("events", "fmus", "belt_speeds", "plant", "observers", "signals")
"""The stages of :meth:`CoSimulation.step`, in order."""


class StageClock:
    """Wall time spent in each stage of :meth:`CoSimulation.step` (``totals_s``), for benchmarks; one
    ``perf_counter`` per stage, so that timing does not change what is timed."""

    def __init__(self) -> None:
        self.totals_s = dict.fromkeys(STAGES, 0.0)
        self._last = 0.0

    def start(self) -> None:
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.totals_s[stage] += now - self._last
        self._last = now

    def reset(self) -> None:
        self.totals_s = dict.fromkeys(STAGES, 0.0)


class _NoClock(StageClock):
    def start(self) -> None:
        pass

    def lap(self, stage: str) -> None:
        pass


NO_CLOCK = _NoClock()
"""The default: no timing."""


class FmuLike(Protocol):
    name: str

    def set(self, values: dict[str, Any]) -> None: ...
    def get(self, names: list[str]) -> dict[str, Any]: ...
    def do_step(self, t_s: float, dt_s: float) -> None: ...
    def terminate(self) -> None: ...


@dataclass
class CoSimulation:
    """State of a running co-simulation; step it with :meth:`step`.  The plant is stepped through its
    ``ports`` (:mod:`plant.sim.ports`) and read through the state it publishes (``plant.state``), nothing else."""

    plant: Plant
    ports: PlantPorts
    fmus: dict[str, FmuLike]
    step_multiples: dict[str, int]
    wiring: Wiring
    events: list[Event]
    comm_step_s: float
    jacobi: bool = False
    recorder: RunRecorder | None = None
    values: dict[str, Any] = field(default_factory=dict)
    overrides: dict[str, tuple[str, Any]] = field(default_factory=dict)
    signals: list[tuple] = field(default_factory=list)
    signal_names: list[str] = field(default_factory=list)
    steps: int = 0
    clock: StageClock = NO_CLOCK
    outfeed: str | None = None
    """The outfeed photo-eye whose blocked edges the fish counts count (``outfeed_count``)."""
    observers: list[StepObserver] = field(default_factory=list)
    """Step observers attached after the energy watch, the fish counts and the recording (:mod:`plant.sim.observers`)."""

    def __post_init__(self) -> None:
        self._inputs_of = {name: self.wiring.into(name) for name in list(self.fmus) + [PLANT]}
        # what is read of each FMU after its step: its connected outputs and its [record]ed variables
        self._outputs_of = {name: sorted({c.source.variable for c in self.wiring.connections
                                          if c.source.component == name}
                                         | {k.partition(".")[2] for k in self.wiring.recorded
                                            if k.partition(".")[0] == name}) for name in self.fmus}
        self.setpoint_sources = self.wiring.setpoints
        self._events = sorted(self.events, key=lambda e: e.t_s)
        self._next_event = 0
        self.signal_names = signal_names(self.wiring)
        self._feeding = {c.target.key: c for c in self.wiring.connections}
        self._sent: dict[str, Any] = {}
        self.energy_watch, self.fish_counts, *self.recording = plant_observers(self.outfeed, self.recorder)
        # the constant inputs' values now: an external input (OPC UA) changes them between steps
        self.constants = dict(self.wiring.constants)
        self._constants_of = {name: [(key, key.partition(".")[2]) for key in self.wiring.constants
                                     if key.partition(".")[0] == name] for name in self.fmus}
        # initial values: FMU outputs after initialisation, the plant at rest
        for name, fmu in self.fmus.items():
            for var, v in fmu.get(self._outputs_of[name]).items():
                self.values[f"{name}.{var}"] = v
        for port, v in self._plant_outputs_at_rest().items():
            self.values[f"{PLANT}.{port}"] = v

    def _plant_outputs_at_rest(self) -> dict[str, Any]:
        return PlantOutputs.at_rest(self.ports).port_values()

    @property
    def t_s(self) -> float:
        return self.steps * self.comm_step_s

    # ---- the step ----------------------------------------------------------------------------
    def step(self) -> None:
        """One base step from t to t + dt, stage by stage (see the module's docstring)."""
        t, dt, lap = self.t_s, self.comm_step_s, self.clock.lap
        self.clock.start()
        self._apply_events(t)
        lap("events")
        held = dict(self.values) if self.jacobi else self.values
        for name in self.wiring.order:
            m = self.step_multiples.get(name, 1)
            if self.steps % m == 0:
                self._step_fmu(name, held, t, m * dt)
        lap("fmus")
        speeds = {c: float(self._input_value(f"{PLANT}.{c}.speed", held)) for c in self.ports.conveyor_ids}
        commands = {d: bool(self._input_value(f"{PLANT}.{d}.command", held)) for d in self.ports.device_ids}
        lap("belt_speeds")
        out = self.plant.step(speeds, commands)
        lap("plant")
        notify((self.energy_watch, self.fish_counts, *self.recording, *self.observers), self.plant.state, out,
               StepInputs(speeds, commands, self._setpoints(speeds, out)), dt)
        lap("observers")
        for port, v in out.port_values().items():
            self.values[f"{PLANT}.{port}"] = v
        self.steps += 1
        self._record()
        lap("signals")

    def _step_fmu(self, name: str, held: dict[str, Any], t: float, dt: float) -> None:
        fmu = self.fmus[name]
        inputs = {}
        for c in self._inputs_of[name]:
            inputs[c.target.variable] = self._sent[c.target.key] = self._transmit(c, held)
        for key, var in self._constants_of[name]:
            inputs[var] = self._sent[key] = self._with_event(key, self.constants[key])
        fmu.set(inputs)
        fmu.do_step(t, dt)
        for var, v in fmu.get(self._outputs_of[name]).items():
            if isinstance(v, float) and not np.isfinite(v):
                raise SimulationError(f"FMU '{name}': output '{var}' is {v}", t + dt)
            self.values[f"{name}.{var}"] = v

    def _input_value(self, key: str, held: dict[str, Any]) -> Any:
        if key in self._feeding:
            value = self._transmit(self._feeding[key], held)
        else:
            value = self._with_event(key, self.constants[key])
        self._sent[key] = value
        return value

    def _transmit(self, c: Connection, held: dict[str, Any]) -> Any:
        """The source's value as the target gets it: an event on the source, the connection's conversion, an
        event on the target (in the target's unit)."""
        if not self.overrides:
            return c.convert(held[c.source.key]) if c.converts else held[c.source.key]
        value = self._with_event(c.source.key, held[c.source.key])
        return self._with_event(c.target.key, c.convert(value) if c.converts else value)

    def set_external(self, key: str, value: Any) -> None:
        """An external input (``[opcua] inputs``) written from outside: used from the next step on, as a PLC's
        outputs are on the next scan.  Converted to the type of its start value (a bool stays a bool)."""
        if key not in self.wiring.external:
            raise KeyError(f"'{key}' is not an external input")
        old = self.constants[key]
        self.constants[key] = type(old)(value) if isinstance(old, (bool, int, float)) else value

    def _with_event(self, key: str, value: Any) -> Any:
        ov = self.overrides.get(key)
        if ov is None:
            return value
        action, v = ov
        if action == "override":
            return type(value)(v) if isinstance(value, (bool, int, float)) else v
        return value + v  # bias

    def _apply_events(self, t: float) -> None:
        while self._next_event < len(self._events) and self._events[self._next_event].t_s <= t + 1e-9:
            ev = self._events[self._next_event]
            if ev.action == "reset":
                self.overrides.pop(ev.target, None)
            else:
                self.overrides[ev.target] = (ev.action, ev.value)
            self._next_event += 1

    # ---- recording ---------------------------------------------------------------------------
    def _setpoints(self, speeds: dict[str, float], out: PlantOutputs) -> dict[str, float]:
        """Each belt's setpoint for belts.csv after this step: its setpoint signal as sent in it (an input) or as it
        is after it (an output: an FMU's, or the plant's in ``out``); the belt's speed where it has none."""
        setpoints = {}
        for c, speed in speeds.items():
            key = self.setpoint_sources.get(c)
            if key is not None and key not in self._sent and key.partition(".")[0] == PLANT:
                setpoints[c] = float(out.port_values()[key.partition(".")[2]])
            else:
                setpoints[c] = float(setpoint_value(key, self._sent, self.values, speed))
        return setpoints

    def _record(self) -> None:
        """signals.csv's row: inputs as they were sent this step, outputs as they are now (before any event on them)."""
        sent, values = self._sent, self.values
        self.signals.append((self.t_s, *[sent[k] if k in sent else values.get(k) for k in self.signal_names]))

    def signal_frame(self) -> pd.DataFrame:
        """Every recorded signal per step (see the module's docstring for the types)."""
        return signal_frame(self.signals, self.signal_names)

    def terminate(self) -> None:
        for fmu in self.fmus.values():
            fmu.terminate()


def signal_frame(rows: list[tuple], names: list[str]) -> pd.DataFrame:
    """``t_s`` and the signals ``names``; with no rows (a run that failed in its first step) an empty
    table with those columns."""
    return pd.DataFrame(rows, columns=["t_s", *names])


def setpoint_value(key: str | None, sent: dict[str, Any], values: dict[str, Any], speed: float) -> Any:
    """A conveyor's setpoint for belts.csv: the signal ``key`` as it was sent (an input) or is (an output); the
    belt's speed where it has none (a belt driven by a plant output)."""
    if key is None:
        return speed
    return sent[key] if key in sent else values.get(key, speed)
