"""Connections between FMU variables and the plant's ports: checked, typed and put in stepping order.

The plant is the component ``plant``; its ports (``plant.<conveyor>.speed`` in, ``.speed``, ``.load_force``,
``.load_mass`` and ``plant.<photo-eye>.blocked`` out, with their types and units) are those its declaration
gives (:mod:`plant.sim.ports`).

A connection ``A.x -> B.y`` (or a ``[[wiring.connection]]`` table) must go from an output to an input; an
input takes at most one connection; every plant input is connected or has a constant in ``[inputs]``.
Values keep their type on the way (Real float, Integer int, Boolean bool, String str; see
:mod:`fishfmu.cosim.master`), or are converted where nothing is lost (:data:`WIDENING`: Integer, Boolean
and Enumeration into Real, Boolean into Integer); a Real into an Integer is rounded only when the
connection says ``round = true``; any other pair of types is refused.  A table may give a linear
transformation, ``gain`` x value + ``offset`` (SSP's LinearTransformation), on numbers.  Events override
or bias numbers and override Booleans, not Strings.

**Units** are checked on every connection, from each end's variable or its declared type (plant ports:
:data:`plant.sim.ports.SIGNALS`): two different units are refused, naming both, unless the connection gives a gain
(which states the conversion); a unitless end connects to anything.  Two names are the same unit when
they are equal or both defined with the same SI base units, factor and offset.

**Coupling.** Gauss-Seidel (default): FMUs are stepped in the order of their connections among
themselves (a controller before the drives it commands), each seeing what its sources produced in
this step, and the plant last, with the drives' fresh belt speeds; FMUs see the plant's outputs of
the previous step, as a PLC sees its sensors one scan late.  Where FMUs feed each other (a
controller reading the speeds of the drives it commands), the one listed first steps first and
the other's value reaches it one step later; only an algebraic loop (a cycle of outputs declared as
direct feedthrough) cannot be ordered and is an input error.  Jacobi: every component sees the
previous step's values, in any order.

Over 450 lines: every check of a scenario's wiring against its FMUs' variables and the plant's ports is here (the
connections, constants, OPC UA inputs, events, bounds and setpoints), each a function of its own, since they share
the lookup of a port and its errors' wording.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from typing import Any

from plant.errors import InputError
from plant.validation import suggest
from plant.contract.line import Line
from plant.sim.ports import SIGNALS, PlantPorts

from fishfmu.fmu.archive import FmuVariable
from fishfmu.scenario.order import stepping_order
from fishfmu.scenario.schema import Scenario

PLANT = "plant"
"""The plant's component name in connections, events and signals (``plant.c1.speed``)."""

WIDENING = {("Integer", "Real"), ("Boolean", "Real"), ("Boolean", "Integer")}
"""(source type, target type) pairs converted without loss (Enumeration is read as Integer)."""


@dataclass(frozen=True)
class Port:
    component: str
    variable: str
    causality: str  # input | output
    type: str
    unit: str | None = None
    unit_base: tuple[float, ...] | None = field(default=None, compare=False)
    """The unit in SI base units where it is defined (see :class:`fishfmu.fmu.archive.FmuVariable`)."""
    value_reference: int | None = field(default=None, compare=False)
    """An FMU variable's value reference: two names with one (and one type) are aliases of one variable."""
    key: str = field(init=False, compare=False)
    """``component.variable``, the name used in connections, events and recorded signals."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "key", f"{self.component}.{self.variable}")

    def same_unit(self, other: "Port") -> bool:
        """Whether the two ends are in one unit (or either has none)."""
        if not self.unit or not other.unit or self.unit == other.unit:
            return True
        return self.unit_base is not None and self.unit_base == other.unit_base


@dataclass(frozen=True)
class Connection:
    source: Port
    target: Port
    gain: float | None = None
    offset: float | None = None
    round: bool = False
    """A Real into an Integer: rounded (halves away from zero)."""
    converts: bool = field(init=False, compare=False)
    """Whether a value changes on the way (a transformation, or a change of type)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "converts", self.gain is not None or self.offset is not None
                           or self.source.type != self.target.type)

    def __str__(self) -> str:
        return f"{self.source.key} -> {self.target.key}"

    def convert(self, value: Any) -> Any:
        """The value the target gets for a source ``value`` (of the source's Python type)."""
        if self.gain is not None or self.offset is not None:
            value = (1.0 if self.gain is None else self.gain) * float(value) + (self.offset or 0.0)
        if self.target.type == "Real":
            return float(value)
        if self.target.type == "Integer":
            if isinstance(value, float):  # checked: only with round = true, or from a transformation with it
                return int(math.copysign(math.floor(abs(value) + 0.5), value))
            return int(value)
        return value


@dataclass
class Wiring:
    connections: list[Connection]
    order: list[str]
    """FMU names in stepping order (the plant is always stepped after them)."""
    constants: dict[str, float | bool] = field(default_factory=dict)
    """Unconnected inputs with a constant value, by ``component.variable``."""
    recorded: list[str] = field(default_factory=list)
    """Variables recorded besides the connected ones and the constants (``[record]``), by ``component.variable``."""
    setpoints: dict[str, str] = field(default_factory=dict)
    """Per conveyor, the signal logged as its setpoint (declared, or derived: see :func:`setpoint_signals`)."""
    jacobi: bool = False
    external: list[str] = field(default_factory=list)
    """Inputs written from outside (``[opcua] inputs``): among ``constants``, with their start value until written."""

    def into(self, component: str) -> list[Connection]:
        return [c for c in self.connections if c.target.component == component]

    def delayed(self) -> list[tuple[Connection, str]]:
        """Connections whose value reaches the target one communication step late, and why: under Gauss-Seidel a
        feedback to an FMU that steps earlier, and every plant output (FMUs step before the plant, as a PLC
        reads its sensors one scan late); under Jacobi every connection."""
        rank = {n: i for i, n in enumerate(self.order)}
        rank[PLANT] = len(self.order)
        out = []
        for c in self.connections:
            if self.jacobi:
                out.append((c, "jacobi coupling: every component sees the values of the previous step"))
            elif c.source.component == PLANT:
                out.append((c, "a plant output: FMUs step before the plant and see its values of the previous step"))
            elif rank[c.source.component] >= rank[c.target.component]:
                out.append((c, f"feedback: '{c.target.component}' steps before '{c.source.component}'"))
        return out

    def describe(self) -> dict:
        """The stepping order, every delayed link, conversion, setpoint and recorded variable (run_info.json,
        ``fishfmu check``)."""
        return {
            "coupling": "jacobi" if self.jacobi else "gauss-seidel",
            "stepping_order": [*self.order, PLANT],
            "delayed_links": [{"connection": str(c), "why": why} for c, why in self.delayed()],
            "conversions": [{"connection": str(c), "from": f"{c.source.type} [{c.source.unit or '-'}]",
                             "to": f"{c.target.type} [{c.target.unit or '-'}]", "gain": c.gain, "offset": c.offset,
                             "round": c.round} for c in self.connections if c.converts],
            "setpoints": dict(self.setpoints),
            "recorded": list(self.recorded),
            "external_inputs": list(self.external),
        }


def plant_ports(line: Line) -> dict[str, list[Port]]:
    """The plant's ports by variable name, from its declaration (``c1.speed`` is both an input and an output)."""
    declared = PlantPorts.of(line)
    inputs, outputs = declared.inputs(), declared.outputs()
    ports: dict[str, list[Port]] = {}
    for name in outputs + [n for n in inputs if n not in outputs]:
        s = SIGNALS[name.rpartition(".")[2]]
        ports[name] = [Port(PLANT, name, causality, s.type, s.unit, s.unit_base)
                       for causality in ("input", "output") if causality == "input" and name in inputs
                       or causality == "output" and s.is_output]
    return ports


def _lookup(scenario_file, component: str, variable: str, want: str, fmus: dict[str, dict[str, FmuVariable]],
            plant: dict[str, list[Port]], where: str) -> Port:
    if component == PLANT:
        candidates = plant.get(variable)
        if candidates is None:
            hint = suggest(variable, plant, prefix="plant.")
            raise InputError(f"the plant has no port '{variable}'{hint}", file=scenario_file, where=where)
        for p in candidates:
            if p.causality == want:
                return p
        raise InputError(f"'plant.{variable}' is an {candidates[0].causality}, it cannot be a "
                         f"{'source' if want == 'output' else 'target'}", file=scenario_file, where=where)
    if component not in fmus:
        hint = suggest(component, [*fmus, PLANT])
        raise InputError(f"no FMU or plant named '{component}'{hint}", file=scenario_file, where=where)
    var = fmus[component].get(variable)
    if var is None:
        hint = suggest(variable, fmus[component], prefix=f"{component}.")
        raise InputError(f"FMU '{component}' has no variable '{variable}'{hint}", file=scenario_file, where=where)
    if var.causality != want:
        raise InputError(f"'{component}.{variable}' is an {var.causality}; a connection needs an "
                         f"{want} {'as source' if want == 'output' else 'as target'}", file=scenario_file, where=where)
    vtype = "Integer" if var.type == "Enumeration" else var.type
    return Port(component, variable, want, vtype, var.unit, var.unit_base, var.value_reference)


def resolve_wiring(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]],
                   scenario_file: str | None = None, feedthrough: dict[str, set[str]] | None = None) -> Wiring:
    """Check every connection, constant input and event target; order the FMUs."""
    plant = plant_ports(scenario.line)
    connections, taken = _connections(scenario, fmu_variables, plant, scenario_file)
    constants = _constant_inputs(scenario, fmu_variables, plant, scenario_file, taken)
    external = _opcua_inputs(scenario, fmu_variables, plant, scenario_file, taken, constants)
    missing = [key for key in (f"{PLANT}.{name}" for name in PlantPorts.of(scenario.line).inputs())
               if key not in taken and key not in constants]
    if missing:
        raise InputError(f"plant input (belt speed, device command) not connected and no constant given for: "
                         f"{', '.join(missing)}",
                         file=scenario_file, where="wiring.connections")
    _check_events(scenario, fmu_variables, plant, scenario_file)
    names = [f.name for f in scenario.fmu]
    if scenario.run.coupling == "jacobi":
        order = names
    else:
        order = stepping_order(names, connections, scenario_file, feedthrough)
    wiring = Wiring(connections, order, constants, jacobi=scenario.run.coupling == "jacobi", external=external)
    wiring.recorded = _recorded(scenario, wiring, fmu_variables, plant, scenario_file)
    signals = _signal_types(wiring, fmu_variables, plant)
    _check_expectations(scenario, signals, scenario_file)
    wiring.setpoints = setpoint_signals(scenario, wiring, signals, scenario_file)
    return wiring


def _connections(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]],
                 scenario_file: str | None) -> tuple[list[Connection], dict[str, tuple[tuple, str]]]:
    """The connections, each checked, and what they take: target key -> (its variable's identity, the source key)."""
    connections: list[Connection] = []
    taken: dict[str, tuple[tuple, str]] = {}
    for spec in scenario.connection_specs():
        where = spec.where
        src = _lookup(scenario_file, *spec.source, "output", fmu_variables, plant, where)
        dst = _lookup(scenario_file, *spec.target, "input", fmu_variables, plant, where)
        conn = Connection(src, dst, spec.gain, spec.offset, spec.round)
        problem = connection_problem(conn)
        if problem:
            raise InputError(problem, file=scenario_file, where=where)
        if dst.key in taken:
            raise InputError(f"'{dst.key}' is connected twice (also from '{taken[dst.key][1]}')", file=scenario_file,
                             where=where)
        same = alias_key(dst)
        twice = next((k for k, (a, _) in taken.items() if a == same and k != dst.key), None)
        if twice is not None:
            raise InputError(f"'{dst.key}' and '{twice}' are one variable (aliases: value reference "
                             f"{dst.value_reference}), connected twice (also from '{taken[twice][1]}')",
                             file=scenario_file, where=where)
        taken[dst.key] = (same, src.key)
        connections.append(conn)
    return connections, taken


def _constant_inputs(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]],
                     scenario_file: str | None, taken: dict[str, tuple[tuple, str]]) -> dict[str, float | bool]:
    """``wiring.inputs``: each a number or boolean for an input no connection sets."""
    constants: dict[str, float | bool] = {}
    for key, value in scenario.wiring.inputs.items():
        comp, _, var = key.partition(".")
        port = _lookup(scenario_file, comp, var, "input", fmu_variables, plant, f"wiring.inputs.{key}")
        if port.key in taken or any(a == alias_key(port) for a, _ in taken.values()):
            raise InputError(f"'{key}' is connected and also given a constant", file=scenario_file,
                             where=f"wiring.inputs.{key}")
        if port.type == "String":
            raise InputError(f"'{key}' is a String input; constants in wiring.inputs are numbers or booleans "
                             "(give it as a parameter start value instead)", file=scenario_file,
                             where=f"wiring.inputs.{key}")
        if port.type == "Boolean" and value not in (0, 1):  # true and false are 1 and 0; 0.5 and 2 are not
            raise InputError(f"'{key}' is a Boolean input: its constant must be true or false (or 1 or 0), not "
                             f"{value!r}", file=scenario_file, where=f"wiring.inputs.{key}")
        constants[port.key] = value
    return constants


def _opcua_inputs(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]],
                  scenario_file: str | None, taken: dict[str, tuple[tuple, str]],
                  constants: dict[str, float | bool]) -> list[str]:
    """``opcua.inputs``: inputs OPC UA clients write, each starting at its start value (added to ``constants``)."""
    external = []
    for i, key in enumerate(scenario.opcua.inputs):
        comp, _, var = key.partition(".")
        where = f"opcua.inputs[{i}]"
        port = _lookup(scenario_file, comp, var, "input", fmu_variables, plant, where)
        if port.key in taken or any(a == alias_key(port) for a, _ in taken.values()):
            raise InputError(f"'{key}' is connected; an input written by OPC UA clients replaces a connection (remove "
                             f"the one from '{taken.get(port.key, (None, '?'))[1]}')", file=scenario_file, where=where)
        if port.key in constants:
            raise InputError(f"'{key}' is also given a constant in wiring.inputs", file=scenario_file, where=where)
        if port.type not in ("Real", "Integer", "Boolean", "Enumeration"):
            raise InputError(f"'{key}' is a {port.type} input; OPC UA clients write numbers and booleans here",
                             file=scenario_file, where=where)
        start = fmu_variables[comp][var].start if comp != PLANT else None
        zero = False if port.type == "Boolean" else 0.0 if port.type == "Real" else 0
        try:
            constants[port.key] = type(zero)(start) if start is not None else zero
        except (TypeError, ValueError):
            constants[port.key] = zero
        external.append(port.key)
    return external


def _check_events(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]],
                  scenario_file: str | None) -> None:
    """Each ``[[event]]`` acts on an input or output whose type its action fits."""
    for i, ev in enumerate(scenario.event):
        comp, _, var = ev.target.partition(".")
        if comp == PLANT:
            if var not in plant:
                _lookup(scenario_file, comp, var, "output", fmu_variables, plant, f"event[{i}].target")
            vtype = plant[var][0].type
        else:
            if comp not in fmu_variables or var not in fmu_variables[comp]:
                _lookup(scenario_file, comp, var, "input", fmu_variables, plant, f"event[{i}].target")
            elif fmu_variables[comp][var].causality not in ("input", "output"):
                raise InputError(f"event target '{ev.target}' is a {fmu_variables[comp][var].causality}; events act on "
                                 "inputs and outputs", file=scenario_file, where=f"event[{i}].target")
            vtype = fmu_variables[comp][var].type
        if vtype == "String" and ev.action != "reset":
            raise InputError(f"event target '{ev.target}' is a String; events set numbers and booleans",
                             file=scenario_file, where=f"event[{i}].target")
        if vtype == "Boolean" and ev.action == "bias":
            raise InputError(f"event target '{ev.target}' is a Boolean; it can be overridden or reset, not biased",
                             file=scenario_file, where=f"event[{i}].action")
        if vtype == "Boolean" and ev.action == "override" and ev.value not in (0, 1):
            raise InputError(f"event target '{ev.target}' is a Boolean: the value must be true or false (or 1 or 0), "
                             f"not {ev.value!r}", file=scenario_file, where=f"event[{i}].value")


def _check_expectations(scenario: Scenario, signals: dict[str, str], scenario_file: str | None) -> None:
    """Each ``[expect]`` bound on a signal names a recorded signal of a type bounds take."""
    for key, bound in scenario.expect.items():
        if "." not in key:
            continue
        if key not in signals:
            hint = suggest(key, signals)
            raise InputError(f"'{key}' is not a recorded signal{hint} (signals are the connected variables, the "
                             "constant inputs and those in [record])", file=scenario_file, where=f"expect.{key}")
        if signals[key] == "String":
            raise InputError(f"'{key}' is a String; bounds take numbers and Booleans", file=scenario_file,
                             where=f"expect.{key}")
        if bound.final is None and bound.tolerance:
            raise InputError("tolerance goes with final", file=scenario_file, where=f"expect.{key}.tolerance")


def alias_key(port: Port) -> tuple:
    """What identifies the variable behind a port: an FMU's value reference and type (aliases share them)."""
    if port.component == PLANT or port.value_reference is None:
        return (port.key,)
    return (port.component, port.type, port.value_reference)


def _recorded(scenario: Scenario, wiring: Wiring, fmus: dict[str, dict[str, FmuVariable]],
              plant: dict[str, list[Port]], scenario_file: str | None) -> list[str]:
    """The variables ``[record]`` names (wildcards expanded, in the FMUs' order), less those recorded anyway;
    of aliases the first name only."""
    every = [f"{n}.{v}" for n, variables in fmus.items() for v in variables] + [f"{PLANT}.{p}" for p in plant]
    anyway = set(signal_names(wiring))
    seen = {alias_key(_any_port(k, fmus, plant)) for k in anyway}
    out: list[str] = []
    for i, pattern in enumerate(scenario.record.variables):
        matched = [k for k in every if fnmatch.fnmatchcase(k, pattern)]
        if not matched:
            comp = pattern.partition(".")[0]
            hint = "" if any(ch in pattern for ch in "*?[") else suggest(pattern, every)
            raise InputError(f"'{pattern}' matches no variable{hint}" + (
                f" (no FMU or plant named '{comp}')" if comp not in fmus and comp != PLANT else ""),
                file=scenario_file, where=f"record.variables[{i}]")
        for k in matched:
            a = alias_key(_any_port(k, fmus, plant))
            if a not in seen:
                seen.add(a)
                out.append(k)
    return out


def _any_port(key: str, fmus: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]]) -> Port:
    comp, _, var = key.partition(".")
    if comp == PLANT:
        return plant[var][-1]
    v = fmus[comp][var]
    return Port(comp, var, v.causality, "Integer" if v.type == "Enumeration" else v.type, v.unit, v.unit_base,
                v.value_reference)


def _signal_types(wiring: Wiring, fmus: dict[str, dict[str, FmuVariable]], plant: dict[str, list[Port]]) -> dict[str, str]:
    """Every recorded signal (:func:`signal_names`) and its type."""
    return {k: _any_port(k, fmus, plant).type for k in signal_names(wiring)}


def signal_names(wiring: Wiring) -> list[str]:
    """The recorded signals: both ends of each connection in order, the constant inputs, then ``[record]``."""
    names: list[str] = []
    for c in wiring.connections:
        for key in (c.source.key, c.target.key):
            if key not in names:
                names.append(key)
    names += [k for k in wiring.constants if k not in names]
    names += [k for k in wiring.recorded if k not in names]
    return names


def setpoint_signals(scenario: Scenario, wiring: Wiring, signals: dict[str, str], scenario_file: str | None
                     ) -> dict[str, str]:
    """Per conveyor, the signal logged as its setpoint in belts.csv: as ``[wiring] setpoints`` declares it, else
    derived from the connections, never from a name.  The component that sets the belt's speed (its drive) is
    commanded by its one input fed by another FMU or a constant (what it received, after any conversion); a
    component with no such input commands the belt itself (its output is the setpoint); a constant belt speed
    is its own setpoint.  A drive with several such inputs must be declared (an InputError says so)."""
    ids = [c.id for c in scenario.line.conveyors]
    out: dict[str, str] = {}
    for cid, key in scenario.wiring.setpoints.items():
        where = f"wiring.setpoints.{cid}"
        if cid not in ids:
            raise InputError(f"no conveyor '{cid}'{suggest(cid, ids)}", file=scenario_file, where=where)
        if key not in signals:
            raise InputError(f"'{key}' is not a recorded signal{suggest(key, signals)} (connect it or add it to "
                             "[record])", file=scenario_file, where=where)
        if signals[key] not in ("Real", "Integer"):
            raise InputError(f"'{key}' is {signals[key]}; a setpoint is a number", file=scenario_file, where=where)
        out[cid] = key
    for cid in ids:
        if cid in out:
            continue
        speed = f"{PLANT}.{cid}.speed"
        feed = next((c for c in wiring.connections if c.target.key == speed), None)
        if feed is None:  # a constant speed
            out[cid] = speed
            continue
        drive = feed.source.component
        if drive == PLANT:
            continue
        commands = [c.target.key for c in wiring.connections if c.target.component == drive
                    and c.source.component != PLANT and c.target.type in ("Real", "Integer")]
        commands += [k for k in wiring.constants if k.partition(".")[0] == drive]
        if len(commands) == 1:
            out[cid] = commands[0]
        elif not commands:
            out[cid] = feed.source.key
        else:
            raise InputError(f"which signal is conveyor '{cid}''s setpoint? its drive '{drive}' is commanded by "
                             f"{', '.join(commands)}: name one as [wiring] setpoints.{cid}", file=scenario_file,
                             where="wiring.setpoints")
    return out


def connection_problem(c: Connection) -> str | None:
    """Why a connection's types, transformation or units do not fit (see the module docstring), or None.

    >>> real = Port("a", "x", "output", "Real", "rpm")
    >>> print(connection_problem(Connection(real, Port("b", "y", "input", "Real", "m/s"))))
    'a.x' is in rpm but 'b.y' in m/s: give the conversion as a gain (and offset) in a [[wiring.connection]] table
    >>> connection_problem(Connection(real, Port("b", "y", "input", "Real", "m/s"), gain=0.001)) is None
    True
    """
    src, dst, transformed = c.source, c.target, c.gain is not None or c.offset is not None
    for end in (src, dst):
        if end.type in ("Array", "Clock"):
            return (f"'{end.key}' is {'an array' if end.type == 'Array' else 'a clock'} variable; connections "
                    "carry single values")
    if transformed and (src.type not in ("Real", "Integer") or dst.type not in ("Real", "Integer")):
        return (f"a gain or offset needs numbers at both ends; '{src.key}' is {src.type} and '{dst.key}' is "
                f"{dst.type}")
    if c.round and dst.type != "Integer":
        return f"round = true rounds into an Integer input; '{dst.key}' is {dst.type}"
    after = "Real" if transformed else src.type  # a transformation computes in floating point
    if after != dst.type and (after, dst.type) not in WIDENING:
        if (after, dst.type) == ("Real", "Integer") and c.round:
            pass
        elif (after, dst.type) == ("Real", "Integer"):
            return (f"'{src.key}' is {src.type}{' (after its gain and offset)' if transformed else ''} but "
                    f"'{dst.key}' is Integer: a narrowing conversion, refused unless the connection says round = true "
                    "(in a [[wiring.connection]] table)")
        else:
            return f"'{src.key}' is {src.type} but '{dst.key}' is {dst.type}: no conversion between them"
    if not src.same_unit(dst) and c.gain is None:
        return (f"'{src.key}' is in {src.unit} but '{dst.key}' in {dst.unit}: give the conversion as a gain "
                "(and offset) in a [[wiring.connection]] table")
    return None
