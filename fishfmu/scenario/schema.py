"""Scenario files: the schema, loading with clear errors and overrides (dotted keys: :mod:`fishfmu.scenario.keys`),
and the resolved form.

A scenario is one TOML file (see ``scenarios/``).  Its tables:

========== =====================================================================================
``[run]``   duration, seed, communication step, coupling scheme, when to stop
``[line]``  the line, exactly as in contracts/measured-data.md (:class:`plant.contract.line.Line`)
``[fish]``  the batch (:class:`plant.fish.population.PopulationSpec`)
``[plant]`` physical and numerical plant parameters (:class:`plant.sim.params.PlantParams`), optional
``[[fmu]]`` FMU instances: a built-in one by name or any FMI 2.0/3.0 co-simulation ``.fmu`` by path,
            with start values (inline or from a parameter file) and a step multiple
``[system]`` ``ssp``: an SSP archive or SSD file whose components, connections and parameter values
            join the scenario (:mod:`fishfmu.scenario.ssp`)
``[wiring]`` ``connections``: ``"source -> target"`` pairs between FMU variables and
            ``plant.<id>.<signal>`` ports, or ``[[wiring.connection]]`` tables with a gain and offset;
            ``inputs``: constants for inputs left unconnected (e.g. ``"plant.c1.speed" = 0.3``)
``[record]`` more variables recorded in ``signals.csv``
``[[event]]`` timed events: at ``t_s`` override, bias or reset a variable (as libcosim's scenarios)
``[kpi]``   which photo-eye counts fish out, the gap a singulated fish needs
``[expect]`` bounds for CI on KPIs (``singulation_rate = { min = 0.4 }``) and recorded signals
========== =====================================================================================

Everything is validated by the pydantic models below, in pydantic's strict mode: a value of the wrong
type is refused, not converted (``gain = "2"`` or ``gain = true`` where a number belongs; an integer is
taken where a float belongs).  A bad file raises :class:`plant.errors.InputError` naming the file, the
dotted key and what is wrong.  FMU variables and plant ports are checked separately when the FMUs are
opened (:mod:`fishfmu.scenario.wiring`).

Over 450 lines: one concept, the scenario file format: a model per table above and the loader that validates
them together (overrides, parameter files, an SSP's additions), the source the scenario reference is generated
from (:mod:`fishfmu.scenario.reference`).
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pydantic
import tomli_w
from pydantic import AfterValidator, Field, PrivateAttr, field_validator, model_validator

from plant.errors import InputError
from plant.contract.kpis import KPI_KEYS
from plant.contract.log_values import detections_bytes_bound
from plant.contract.line import KpiSettings, Line
from plant.sim.params import PlantParams
from plant.contract.devices import device_shapes, device_step_limit_mps, step_for_devices
from plant.fish.fish_body import MIN_SPHERE_RADIUS_M
from plant.fish.population import PopulationSpec, lane_across, tallest_fish_m
from plant.validation import MAX_CSV_BYTES, Strict, ValueAtKey, read_toml, suggest, validate

from fishfmu.scenario.keys import set_dotted
from fishfmu.scenario.ssp import SspSystem, read_parameter_file, read_ssp, start_value_problem
from fishfmu.scenario.ssp_plant import (PLANT_COMPONENT, check_plant_agrees, plant_component, plant_links,
                                        scenario_data)

Name = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", min_length=1, max_length=64)]
MAX_FMUS = 64
"""FMU instances in a scenario, its own ``[[fmu]]`` and those ``[system] ssp`` brings in together."""
MAX_CONNECTION_TABLES = 2000
"""``[[wiring.connection]]`` tables, the scenario's own and the connections ``[system] ssp`` brings in together."""


def _finite(value: Any) -> Any:
    """A value handed to an FMU must be a finite number, a boolean or a string (:func:`start_value_problem`)."""
    problem = start_value_problem(value)
    if problem:
        raise ValueError(f"must be a finite number, a boolean or a string: {problem}")
    return value


FmuValue = Annotated[float | int | bool | str, AfterValidator(_finite)]
"""A parameter value for an FMU: finite numbers, booleans, strings."""
CONNECTION_RE = re.compile(r"^\s*([A-Za-z_][\w]*)\.([\w.\[\]]+)\s*->\s*([A-Za-z_][\w]*)\.([\w.\[\]]+)\s*$")
ENDPOINT_RE = re.compile(r"^\s*([A-Za-z_][\w]*)\.([\w.\[\]]+)\s*$")


class RunSettings(Strict):
    """How long, with which seed and communication step, and how the components are coupled."""

    name: str = Field("run", min_length=1, max_length=80, pattern=r"^[\w\-. ]+$", description=(
        "names the run in the KPI table, the report, the JUnit suite and the recorded run; the default "
        "output folder is named after the scenario file instead"))
    duration_s: float = Field(60.0, gt=0.0, le=24 * 3600.0, description=(
        "simulated time; the run ends earlier with stop_when_clear"))
    seed: int = Field(1, ge=0, le=2**32 - 1, description=(
        "seed of the random draws (fish sizes and drops, with fish.seed_offset): the same seed gives the "
        "same run; --seed overrides it"))
    comm_step_s: float = Field(0.01, ge=0.001, le=0.1, description=(
        "base communication step of the master; a whole multiple of plant.numerics.step_s"))
    coupling: Literal["gauss-seidel", "jacobi"] = Field("gauss-seidel", description=(
        "gauss-seidel: components stepped in dependency order, each seeing the values its sources produced "
        "this step (the plant last); jacobi: every component sees the values of the previous step"))
    stop_when_clear: bool = Field(True, description="end the run one second after the last fish has left the line")
    fmu_process: Literal["in-process", "worker"] = Field("in-process", description=(
        "worker: run each FMU in a separate process, so that a crashing or hanging FMU cannot take the "
        "run down (costs time per step)"))
    fmu_step_timeout_s: float = Field(10.0, gt=0.0, le=3600.0, description="worker mode: longest a doStep may take")


class FmuInstance(Strict):
    """One FMU instance: ``builtin`` (a name from ``fishfmu build-fmus``) or ``path`` to a ``.fmu``."""

    name: Name = Field(description=(
        "instance name, used as '<name>.<variable>' in [wiring] and [[event]]; unique, and not 'plant'"))
    builtin: Literal["conveyor_drive", "singulation_controller"] | None = Field(None, description=(
        "an FMU fishfmu builds (conveyor_drive: a gearmotor on an inverter driving a belt; "
        "singulation_controller: PLC-style speed profile, gap control and jam detection); give this or path"))
    path: str | None = Field(None, description=(
        "an FMI 2.0 or 3.0 co-simulation .fmu file, relative to the scenario file; give this or builtin"))
    step_multiple: int = Field(1, ge=1, le=10000, description="the FMU steps every this many base steps")
    parameters: dict[str, FmuValue] = Field(default_factory=dict, description=(
        "start values by variable name: parameters, inputs, and states or outputs declared with initial = exact "
        "or approx (what FMI allows), checked against its modelDescription; "
        "finite numbers, booleans or strings"))
    parameter_file: str | None = Field(None, description=(
        "start values from a file, relative to the scenario: an SSP parameter-value file (.ssv) or a TOML table of "
        "'variable = value'; values in parameters win over the file's"))
    _origin: str | None = PrivateAttr(None)
    _units: dict[str, str] = PrivateAttr(default_factory=dict)
    _ssp_source: tuple[str, str] | None = PrivateAttr(None)

    @property
    def origin(self) -> str | None:
        """Where an FMU imported from ``[system] ssp`` came from (for errors); None for a ``[[fmu]]`` of the file."""
        return self._origin

    @property
    def ssp_source(self) -> tuple[str, str] | None:
        """An FMU imported from ``[system] ssp``: (the SSP file, the component's source there), what an error about
        its FMU file names (``path`` is fishfmu's copy in the cache); None for a ``[[fmu]]`` of the file."""
        return self._ssp_source

    @property
    def stated_units(self) -> dict[str, str]:
        """Units that a parameter file states for its values, by variable: checked against the FMU's."""
        return self._units

    @model_validator(mode="after")
    def _one_source(self) -> "FmuInstance":
        if (self.builtin is None) == (self.path is None):
            raise ValueAtKey("path", f"FMU '{self.name}': give exactly one of 'builtin' or 'path'")
        return self


class Event(Strict):
    """At ``t_s``: ``override`` a variable's value, ``bias`` it (add), or ``reset`` it to normal."""

    t_s: float = Field(ge=0.0, description="simulation time; applied at the first communication step at or after it")
    target: str = Field(description="'<fmu>.<variable>' or 'plant.<id>.<signal>'")
    action: Literal["override", "bias", "reset"] = Field(description=(
        "override: the variable takes value; bias: value is added to it; reset: back to its own value"))
    value: Annotated[float | bool | None, AfterValidator(_finite)] = Field(None, description=(
        "the value to set or add; needed by override and bias, finite"))

    @model_validator(mode="after")
    def _value_needed(self) -> "Event":
        if self.action != "reset" and self.value is None:
            raise ValueAtKey("value", f"event '{self.action}' of '{self.target}' needs a value")
        if "." not in self.target:
            raise ValueAtKey("target", f"event target '{self.target}' must be '<fmu>.<variable>' or 'plant.<id>.<signal>'")
        return self


class ConnectionTable(Strict):
    """One connection in table form (``[[wiring.connection]]``), with an optional linear transformation."""

    model_config = pydantic.ConfigDict(populate_by_name=True)
    from_: str = Field(alias="from", pattern=ENDPOINT_RE.pattern, description=(
        "the source, an output: '<fmu>.<variable>' or 'plant.<id>.<signal>'"))
    to: str = Field(pattern=ENDPOINT_RE.pattern, description="the target, an input: '<fmu>.<variable>' or 'plant.<id>.speed'")
    gain: Annotated[float, AfterValidator(_finite)] | None = Field(None, description=(
        "the target gets gain x source + offset (SSP's LinearTransformation factor); giving it states the "
        "conversion between the two ends' units"))
    offset: Annotated[float, AfterValidator(_finite)] | None = Field(None, description=(
        "added after the gain, in the target's unit (SSP's LinearTransformation offset)"))
    round: bool = Field(False, description=(
        "a Real value into an Integer input: rounded to the nearest integer (halves away from zero); a "
        "narrowing conversion is refused without it"))
    _origin: str | None = PrivateAttr(None)
    """Where a connection imported from ``[system] ssp`` came from (for errors)."""

    @property
    def origin(self) -> str | None:
        return self._origin


@dataclass(frozen=True)
class ConnectionSpec:
    """A connection as the scenario gives it (either form), before it is checked against the FMUs."""

    source: tuple[str, str]
    """(component, variable)"""
    target: tuple[str, str]
    gain: float | None
    offset: float | None
    round: bool
    where: str
    """The scenario key it came from, for errors: ``wiring.connections[2]`` or ``wiring.connection[0]``."""


class WiringSpec(Strict):
    """Connections between FMU variables and plant ports, and constants for unconnected inputs."""

    connections: list[str] = Field(default_factory=list, max_length=2000, description=(
        "'source.variable -> target.variable' pairs between FMU variables and plant ports "
        "('plant.<id>.<signal>'), checked against each modelDescription and the plant's ports "
        "(names, causality, types)"))
    connection: list[ConnectionTable] = Field(default_factory=list, max_length=MAX_CONNECTION_TABLES, description=(
        "connections in table form, '[[wiring.connection]]' with 'from', 'to' and optionally 'gain', "
        "'offset' (a linear transformation) and 'round' (Real into Integer)"))
    inputs: dict[str, Annotated[float | bool, AfterValidator(_finite)]] = Field(default_factory=dict, description=(
        "constants for inputs left unconnected, by '<fmu>.<variable>' or 'plant.<id>.<signal>' "
        "(e.g. \"plant.c1.speed\" = 0.3)"))
    setpoints: dict[str, str] = Field(default_factory=dict, description=(
        "per conveyor id, the signal logged as its setpoint in belts.csv (e.g. c1 = \"drive_c1.speed_setpoint\"); "
        "where not given: the one input of the component driving the belt that another FMU or a constant "
        "feeds, or that component's output when it has none (several: name it here)"))

    @field_validator("connections")
    @classmethod
    def _connections_parse(cls, value: list[str]) -> list[str]:
        for i, c in enumerate(value):
            if not CONNECTION_RE.match(c):
                raise ValueError(f"connections[{i}] = '{c}' is not of the form 'source.variable -> target.variable'")
        return value


class Bound(Strict):
    """A bound for CI on one KPI (``min``, ``max`` or both) or on one recorded signal (also ``final``); a run
    outside it exits with 1."""

    min: float | None = Field(None, allow_inf_nan=False, description=(
        "the KPI (a signal: every recorded value) must be at least this; a finite number"))
    max: float | None = Field(None, allow_inf_nan=False, description=(
        "the KPI (a signal: every recorded value) must be at most this; a finite number"))
    final: float | None = Field(None, allow_inf_nan=False, description=(
        "a signal only: its value at the end of the run, within tolerance; a finite number"))
    tolerance: float = Field(0.0, ge=0.0, allow_inf_nan=False, description=(
        "a signal's final value may differ from final by this much"))

    @model_validator(mode="after")
    def _some(self) -> "Bound":
        if self.min is None and self.max is None and self.final is None:
            raise ValueAtKey("min", "give min, max or both (a signal: or final)")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueAtKey("min", f"min ({self.min}) is above max ({self.max})")
        return self


class SystemSpec(Strict):
    """FMUs, connections and parameter values from an SSP (System Structure and Parameterization) file."""

    ssp: str | None = Field(None, description=(
        "an .ssp archive or .ssd file, relative to the scenario: its FMU components (SSP 1.0) join [[fmu]] under "
        "their component names, its connections (with linear transformations) join the wiring, and its "
        "parameter values become start values; connections to the plant stay in [wiring]. What it brings in counts "
        f"towards the limits of [[fmu]] ({MAX_FMUS}) and [[wiring.connection]] ({MAX_CONNECTION_TABLES})"))


class OpcuaSpec(Strict):
    """``fishfmu serve``: the line as an OPC UA server; which inputs its clients (a PLC) write."""

    inputs: list[Annotated[str, Field(pattern=ENDPOINT_RE.pattern)]] = Field(default_factory=list, max_length=1000,
                                                                              description=(
        "'<fmu>.<variable>' or 'plant.<id>.speed' inputs written by OPC UA clients instead of a connection (e.g. "
        "the drives' setpoints, replacing the controller FMU); checked like the wiring; a written value takes "
        "effect at the next communication step. Outside serve they hold their start value"))


class RecordSpec(Strict):
    """FMU variables and plant ports recorded in ``signals.csv`` besides the connected ones."""

    variables: list[Annotated[str, Field(min_length=3, pattern=r"^[A-Za-z_][\w]*\.")]] = Field(
        default_factory=list, max_length=1000, description=(
            "'<fmu>.<variable>' or 'plant.<id>.<signal>' names, or wildcards ('vdp.*', 'drive_*.motor_speed'); "
            "each must match some variable; an FMU's variables are read after each of its steps"))


"""How much of a fish's smallest contact sphere a device may move in one integration step: with the 1.25 ms step and
12 mm spheres, 2.4 m/s.  A pusher's paddle hitting a fish at 4.8 and 8.3 m/s (4 and 7 mm a step) gave it energy
from nowhere (the contact's explicit step), at 12.5 and 25 m/s it passed through it; at 2.0 .. 2.4 m/s (three places
of the fish) and 6.25 m/s it pushed it out (tests/test_devices.py)."""


class Scenario(Strict):
    """A whole scenario file."""

    run: RunSettings = Field(default_factory=RunSettings)
    line: Line
    fish: PopulationSpec = Field(default_factory=PopulationSpec)
    plant: PlantParams = Field(default_factory=PlantParams)
    fmu: list[FmuInstance] = Field(default_factory=list, max_length=MAX_FMUS)
    system: SystemSpec = Field(default_factory=SystemSpec)
    _ssp_not_imported: list[str] = PrivateAttr(default_factory=list)

    @property
    def ssp_not_imported(self) -> list[str]:
        """Connections of ``[system] ssp`` to the system's own connectors, which are not imported (``fishfmu check``)."""
        return self._ssp_not_imported
    wiring: WiringSpec = Field(default_factory=WiringSpec)
    event: list[Event] = Field(default_factory=list, max_length=10000)
    kpi: KpiSettings
    record: RecordSpec = Field(default_factory=RecordSpec)
    opcua: OpcuaSpec = Field(default_factory=OpcuaSpec)
    expect: dict[str, Bound] = Field(default_factory=dict, description=(
        "bounds by KPI (contracts/kpis.md): " + ", ".join(KPI_KEYS) + "; or by recorded signal "
        "('\"drive_c1.belt_speed\" = { max = 1.5 }', a connected or [record]ed name)"))

    @field_validator("expect")
    @classmethod
    def _expect_keys(cls, value: dict[str, Bound]) -> dict[str, Bound]:
        for k, b in value.items():
            if "." in k:  # a signal, checked against the wiring when the FMUs are open
                continue
            if k not in KPI_KEYS:
                raise ValueError(f"unknown KPI '{k}'{suggest(k, KPI_KEYS, allowed='KPIs')} (a signal is named "
                                 "'<component>.<variable>')")
            if b.final is not None:
                raise ValueError(f"'{k}': final bounds a signal's last value; a KPI takes min and max")
        return value

    @model_validator(mode="after")
    def _cross_checks(self) -> "Scenario":
        self.kpi.check_against(self.line)
        names = [f.name for f in self.fmu]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueAtKey("fmu", f"FMU names must be unique; repeated: {', '.join(dup)}")
        if "plant" in names:
            raise ValueAtKey(f"fmu[{names.index('plant')}].name", "'plant' is reserved for the plant's ports; rename the FMU")
        numerics = self.plant.numerics
        if "step_s" not in numerics.model_fields_set:  # the fish model's own step, shorter where a device needs it
            numerics.step_s = step_for_devices(self.line, self.run.comm_step_s, numerics.step_s)
            numerics.model_fields_set.discard("step_s")
        n_base = self.run.comm_step_s / self.plant.numerics.step_s
        if abs(n_base - round(n_base)) > 1e-6:
            raise ValueAtKey("run.comm_step_s", f"{self.run.comm_step_s} s must be a whole multiple of "
                             f"plant.numerics.step_s ({self.plant.numerics.step_s})")
        longest = self.fish.length_max_m
        if self.line.conveyors[0].length_m < longest:
            raise ValueAtKey("fish.length_max_m", f"the first conveyor ('{self.line.conveyors[0].id}', {self.line.conveyors[0].length_m} m) "
                             f"is shorter than the longest fish (fish.length_max_m = {longest} m)")
        self._check_device_speeds()
        first = self.line.conveyors[0]
        _, half = lane_across(*self.line.guide_y_at(np.linspace(first.x_start_m, first.x_end_m, 51)))
        if 2.0 * half < tallest_fish_m(self.fish):
            raise ValueAtKey("line.guides", f"the lane between the guides all along the infeed ('{first.id}') is "
                             f"{2.0 * half:.3f} m wide: fish are dropped there lying on their side, and the longest "
                             f"(fish.length_max_m = {longest} m) is {tallest_fish_m(self.fish):.3f} m tall")
        for i, c in enumerate(self.line.conveyors):
            if c.length_m < longest:
                raise ValueAtKey(f"line.conveyors[{i}].length_m", f"{c.length_m} m ('{c.id}') is shorter than the "
                                 f"longest fish (fish.length_max_m = {longest} m): a fish must fit on every belt")
        logged = detections_bytes_bound(self.line.cameras, self.run.duration_s, self.fish.count)
        if logged > MAX_CSV_BYTES:  # what fishfmu writes it must read back (compare, diagnose)
            frames = sum(math.floor(c.rate_hz * self.run.duration_s) + 1 for c in self.line.cameras)
            raise ValueAtKey("line.cameras", f"{len(self.line.cameras)} camera(s) take {frames} frames in run.duration_s "
                             f"= {self.run.duration_s:g} s, each frame a row per fish in view (up to fish.count = "
                             f"{self.fish.count}): detections.csv could reach {logged / 1024**2:.0f} MB, and fishfmu "
                             f"reads a CSV of at most {MAX_CSV_BYTES / 1024**2:.0f} MB; use fewer cameras, a lower "
                             "rate_hz, a shorter run or fewer fish")
        return self

    def _check_device_speeds(self) -> None:
        """A device whose fastest point moves more than a quarter of a fish's smallest contact sphere in one
        integration step hits fish too hard for the step, or passes through them: refused, naming it."""
        step_s = self.plant.numerics.step_s
        limit_mps = device_step_limit_mps(step_s)
        for i, shape in enumerate(device_shapes(self.line)):
            if shape.fastest_mps > limit_mps:
                d = shape.device
                raise ValueAtKey(f"line.devices[{i}].stroke_s", (
                    f"{d.kind} '{d.id}' moves at {shape.fastest_mps:.1f} m/s (its whole travel in {d.stroke_s:g} s): "
                    f"faster than {limit_mps:.1f} m/s, a quarter of a fish's smallest contact sphere "
                    f"({1000 * MIN_SPHERE_RADIUS_M:g} mm) per integration step (plant.numerics.step_s = {step_s:g} s), "
                    f"it would hit fish too hard for the step or pass through them; make stroke_s at least "
                    f"{d.stroke_s * shape.fastest_mps / limit_mps:.3f} s or the step shorter"))

    def connection_specs(self) -> list[ConnectionSpec]:
        """Every connection, the string form's first, then the table form's."""
        out = []
        for i, c in enumerate(self.wiring.connections):
            m = CONNECTION_RE.match(c)
            assert m is not None
            out.append(ConnectionSpec((m.group(1), m.group(2)), (m.group(3), m.group(4)), None, None, False,
                                      f"wiring.connections[{i}]"))
        for i, t in enumerate(self.wiring.connection):
            src, dst = ENDPOINT_RE.match(t.from_), ENDPOINT_RE.match(t.to)
            assert src is not None and dst is not None
            out.append(ConnectionSpec((src.group(1), src.group(2)), (dst.group(1), dst.group(2)), t.gain, t.offset,
                                      t.round, t._origin or f"wiring.connection[{i}]"))
        return out


SSP_SUFFIXES = (".ssp", ".ssd")
"""A scenario given as an SSP (``fishfmu export-ssp``'s archive): its plant component carries the line."""


def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None) -> Scenario:
    """Read, apply ``overrides`` (dotted keys, e.g. ``{"fish.count": 30}``) and validate a scenario file.

    Relative FMU, SSP and STL paths are made absolute against the scenario's folder.
    """
    return ScenarioLoader(path).load(overrides)


def _absolute(scenario_file: Path, name: str, key: str) -> str:
    """``name``, a path the scenario at ``key`` gives relative to itself, made absolute; a NUL in it is bad input."""
    try:
        return str((scenario_file.parent / name).resolve())
    except (ValueError, OSError) as exc:  # "embedded null byte"
        raise InputError(f"not a usable path: {exc}", file=scenario_file, where=key) from None


class ScenarioLoader:
    """One scenario file loaded with overrides, as often as asked (a sweep's points): the file is read once,
    each parameter file and SSP once (as they were when first read); every load validates the whole scenario."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._parameter_files: dict[str, tuple[dict[str, Any], dict[str, str]]] = {}
        self._systems: dict[tuple[str, int, int], SspSystem] = {}
        if self.path.suffix.lower() in SSP_SUFFIXES:  # a whole line exported by export-ssp (fishfmu.scenario.ssp_plant)
            ssp = self.path.resolve()
            system = self._read_ssp(ssp, MAX_FMUS, MAX_CONNECTION_TABLES)
            self.data = scenario_data(ssp, system)
        else:
            self.data = read_toml(self.path)
        """The file's TOML, as read (never changed: each load works on a copy)."""

    def load(self, overrides: dict[str, Any] | None = None) -> Scenario:
        path = self.path
        data = copy.deepcopy(self.data)
        for key, value in (overrides or {}).items():
            set_dotted(data, key, value, file=path)
        fmus = data.get("fmu")
        for i, f in enumerate(fmus if isinstance(fmus, list) else []):  # any other value: refused by the schema
            for key in ("path", "parameter_file"):
                if isinstance(f, dict) and isinstance(f.get(key), str) and not Path(f[key]).is_absolute():
                    data["fmu"][i] = f = dict(f, **{key: _absolute(path, f[key], f"fmu[{i}].{key}")})
        line = data.get("line")
        for i, part in enumerate(line.get("parts", []) if isinstance(line, dict) and isinstance(line.get("parts"), list)
                                 else []):
            if isinstance(part, dict) and isinstance(part.get("stl"), str) and not Path(part["stl"]).is_absolute():
                line["parts"][i] = dict(part, stl=_absolute(path, part["stl"], f"line.parts[{i}].stl"))
        system = data.get("system")
        if isinstance(system, dict) and isinstance(system.get("ssp"), str) and not Path(system["ssp"]).is_absolute():
            data["system"] = dict(system, ssp=_absolute(path, system["ssp"], "system.ssp"))
        scenario = validate(Scenario, data, file=path, strict=True)
        for i, f in enumerate(scenario.fmu):
            if f.parameter_file is not None:
                values, units = self._parameter_file(f.parameter_file, f"fmu[{i}].parameter_file")
                inline = f.parameters
                f.parameters = {**values, **inline}  # each value checked by read_parameter_file, naming the file
                f._units = {k: u for k, u in units.items() if k not in inline}
        if scenario.system.ssp is not None:
            _add_ssp_system(scenario, Path(scenario.system.ssp), path, self._read_ssp)
        return scenario

    def _parameter_file(self, file: str, where: str) -> tuple[dict[str, Any], dict[str, str]]:
        if file not in self._parameter_files:
            self._parameter_files[file] = read_parameter_file(Path(file), self.path, where)
        return self._parameter_files[file]

    def _read_ssp(self, ssp: Path, max_components: int, max_connections: int) -> SspSystem:
        key = (str(ssp), max_components, max_connections)
        if key not in self._systems:
            self._systems[key] = read_ssp(ssp, max_components, max_connections)
        return self._systems[key]


def _add_ssp_system(scenario: Scenario, ssp: Path, scenario_file: Path,
                    read: Callable[[Path, int, int], SspSystem] = read_ssp) -> None:
    """Add an SSP's FMUs and connections to a loaded scenario (checked like the file's own entries when the FMUs
    are opened); their names must not clash with the scenario's, and the limits hold for the whole.  A fishfmu plant
    component is the plant (:mod:`fishfmu.scenario.ssp_plant`)."""
    system = read(ssp, MAX_FMUS - len(scenario.fmu), MAX_CONNECTION_TABLES - len(scenario.wiring.connection))
    found = plant_component(system, ssp)
    links = [(c.source, c.target) for c in system.connections]
    if found is not None:
        links = plant_links(system, found[0])
        if scenario_file.suffix.lower() not in SSP_SUFFIXES:
            check_plant_agrees(found[0], scenario.run.seed, scenario.fish.count, dict(scenario.wiring.inputs), ssp,
                               scenario_file)
    taken = {f.name for f in scenario.fmu} | {PLANT_COMPONENT}
    where = f"system.ssp ({ssp.name})"
    for comp in system.components:
        if found is not None and comp is found[0]:
            continue
        if comp.name in taken:
            raise InputError(f"component '{comp.name}' of {ssp.name} has the name of an [[fmu]] of the scenario "
                             "(or 'plant'); rename one", file=scenario_file, where="system.ssp")
        try:
            entry = FmuInstance(name=comp.name, path=str(comp.fmu), parameters=comp.parameters)
        except pydantic.ValidationError as exc:
            err = exc.errors()[0]
            key = ".".join(str(p) for p in err["loc"])
            raise InputError(f"component '{comp.name}': {key}: {err['msg']}", file=ssp) from None
        entry._origin, entry._units = f"{where}: component '{comp.name}'", dict(comp.units)
        entry._ssp_source = (str(ssp), comp.source)
        scenario.fmu.append(entry)
    scenario._ssp_not_imported = list(system.boundary)
    for conn, (source, target) in zip(system.connections, links):
        text = f"connection {conn.source} -> {conn.target}"
        for end in (source, target):
            if not ENDPOINT_RE.match(end):
                raise InputError(f"{text}: '{end}' is not a '<component>.<variable>' name fishfmu can connect "
                                 "(letters, digits, _ . [ ])", file=ssp)
        try:
            table = ConnectionTable(**{"from": source, "to": target, "gain": conn.gain,
                                       "offset": conn.offset})
        except pydantic.ValidationError as exc:
            raise InputError(f"{text}: {exc.errors()[0]['msg']}", file=ssp) from None
        table._origin = f"{where}: {text}"
        scenario.wiring.connection.append(table)


def resolved_toml(scenario: Scenario) -> str:
    """The scenario with every default filled in, as TOML (what a run actually used)."""
    data = scenario.model_dump(mode="json", exclude_none=True, by_alias=True)
    # what [system] ssp brought in is not written out: loading the resolved file imports it again
    data["fmu"] = [d for d, f in zip(data["fmu"], scenario.fmu) if f.origin is None]
    data["wiring"]["connection"] = [d for d, c in zip(data["wiring"]["connection"], scenario.wiring.connection)
                                    if c._origin is None]
    return tomli_w.dumps(_drop_empty(copy.deepcopy(data)))


def _drop_empty(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_empty(v) for k, v in d.items() if v not in ({}, [])}
    if isinstance(d, list):
        return [_drop_empty(v) for v in d]
    return d
