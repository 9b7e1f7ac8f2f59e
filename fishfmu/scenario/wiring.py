"""Connections between FMU variables and the plant's ports: checked, typed and put in stepping order.

Ports of the plant (component ``plant``), per conveyor ``c`` and photo-eye ``p``:

- inputs: ``plant.<c>.speed`` (Real, m/s): the belt surface speed for the coming step;
- outputs: ``plant.<c>.speed`` (Real, the speed it ran at), ``plant.<c>.load_force`` (Real, N, the
  fish's force on the belt against its motion), ``plant.<c>.load_mass`` (Real, kg, mass resting on
  it), ``plant.<p>.blocked`` (Boolean).

A connection ``A.x -> B.y`` must go from an output to an input of the same type; an input takes at
most one connection; every plant input is connected or has a constant in ``[inputs]``.  Values keep
their type on the way (Real float, Integer int, Boolean bool, String str; see
:mod:`fishfmu.cosim.master`); events override or bias numbers and override Booleans, not Strings.

**Coupling.** Gauss-Seidel (default): FMUs are stepped in the order of their connections among
themselves (a controller before the drives it commands), each seeing what its sources produced in
this step, and the plant last, with the drives' fresh belt speeds; FMUs see the plant's outputs of
the previous step, as a PLC sees its sensors one scan late.  Where FMUs feed each other (a
controller reading the speeds of the drives it commands), the one listed first steps first and
the other's value reaches it one step later; only an algebraic loop (a cycle of outputs declared as
direct feedthrough) cannot be ordered and is an input error.  Jacobi: every component sees the
previous step's values, in any order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from plant.errors import InputError
from plant.validation import suggest
from plant.line import Line

from fishfmu.fmu.archive import FmuVariable
from fishfmu.scenario.schema import Scenario

PLANT = "plant"


@dataclass(frozen=True)
class Port:
    component: str
    variable: str
    causality: str  # input | output
    type: str
    key: str = field(init=False, compare=False)
    """``component.variable``, the name used in connections, events and recorded signals."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "key", f"{self.component}.{self.variable}")


@dataclass(frozen=True)
class Connection:
    source: Port
    target: Port

    def __str__(self) -> str:
        return f"{self.source.key} -> {self.target.key}"


@dataclass
class Wiring:
    connections: list[Connection]
    order: list[str]
    """FMU names in stepping order (the plant is always stepped after them)."""
    constants: dict[str, float | bool] = field(default_factory=dict)
    """Unconnected inputs with a constant value, by ``component.variable``."""

    def into(self, component: str) -> list[Connection]:
        return [c for c in self.connections if c.target.component == component]


def plant_ports(line: Line) -> dict[str, list[Port]]:
    """The plant's ports by variable name (``c1.speed`` is both an input and an output)."""
    ports: dict[str, list[Port]] = {}
    for c in line.conveyors:
        ports[f"{c.id}.speed"] = [Port(PLANT, f"{c.id}.speed", "input", "Real"),
                                  Port(PLANT, f"{c.id}.speed", "output", "Real")]
        ports[f"{c.id}.load_force"] = [Port(PLANT, f"{c.id}.load_force", "output", "Real")]
        ports[f"{c.id}.load_mass"] = [Port(PLANT, f"{c.id}.load_mass", "output", "Real")]
    for p in line.photoeyes:
        ports[f"{p.id}.blocked"] = [Port(PLANT, f"{p.id}.blocked", "output", "Boolean")]
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
    return Port(component, variable, want, vtype)


def resolve_wiring(scenario: Scenario, fmu_variables: dict[str, dict[str, FmuVariable]],
                   scenario_file: str | None = None, feedthrough: dict[str, set[str]] | None = None) -> Wiring:
    """Check every connection, constant input and event target; order the FMUs."""
    plant = plant_ports(scenario.line)
    connections: list[Connection] = []
    taken: dict[str, str] = {}
    for i, (sc, sv, tc, tv) in enumerate(scenario.connection_pairs()):
        where = f"wiring.connections[{i}]"
        src = _lookup(scenario_file, sc, sv, "output", fmu_variables, plant, where)
        dst = _lookup(scenario_file, tc, tv, "input", fmu_variables, plant, where)
        if src.type != dst.type:
            raise InputError(f"'{src.key}' is {src.type} but '{dst.key}' is {dst.type}", file=scenario_file, where=where)
        if dst.key in taken:
            raise InputError(f"'{dst.key}' is connected twice (also from '{taken[dst.key]}')", file=scenario_file,
                             where=where)
        taken[dst.key] = src.key
        connections.append(Connection(src, dst))

    constants: dict[str, float | bool] = {}
    for key, value in scenario.wiring.inputs.items():
        comp, _, var = key.partition(".")
        port = _lookup(scenario_file, comp, var, "input", fmu_variables, plant, f"wiring.inputs.{key}")
        if port.key in taken:
            raise InputError(f"'{key}' is connected and also given a constant", file=scenario_file,
                             where=f"wiring.inputs.{key}")
        if port.type == "String":
            raise InputError(f"'{key}' is a String input; constants in wiring.inputs are numbers or booleans "
                             "(give it as a parameter start value instead)", file=scenario_file,
                             where=f"wiring.inputs.{key}")
        constants[port.key] = value

    missing = [f"plant.{c.id}.speed" for c in scenario.line.conveyors
               if f"plant.{c.id}.speed" not in taken and f"plant.{c.id}.speed" not in constants]
    if missing:
        raise InputError(f"belt speed not connected and no constant given for: {', '.join(missing)}",
                         file=scenario_file, where="wiring.connections")

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

    names = [f.name for f in scenario.fmu]
    if scenario.run.coupling == "jacobi":
        order = names
    else:
        order = _topological(names, connections, scenario_file, feedthrough)
    return Wiring(connections, order, constants)


def direct_feedthrough(model_description) -> set[str]:
    """Outputs whose value after a step depends directly on an input at that time, as declared in
    the modelDescription's ModelStructure (an output without a ``dependencies`` list is read as
    depending on its FMU's state: in co-simulation, outputs come out of doStep)."""
    inputs = {v.name for v in model_description.modelVariables if v.causality == "input"}
    out = set()
    for u in model_description.outputs:
        if u.dependencies and any(d.name in inputs for d in u.dependencies):
            out.add(u.variable.name)
    return out


def _topological(names: list[str], connections: list[Connection], scenario_file: str | None,
                 feedthrough: dict[str, set[str]] | None = None) -> list[str]:
    """FMUs ordered so that each comes after the FMUs it reads from.

    Where FMUs feed each other in a cycle, the one listed first in the scenario steps first and
    sees the others' values from the previous step (as a PLC reads its inputs one scan late).  A
    cycle made only of outputs declared as direct feedthrough is an algebraic loop: an error.
    """
    feedthrough = feedthrough or {}
    edges = {(c.source.component, c.target.component) for c in connections
             if c.source.component in names and c.target.component in names and c.source.component != c.target.component}
    direct = {(c.source.component, c.target.component) for c in connections
              if (c.source.component, c.target.component) in edges
              and c.source.variable in feedthrough.get(c.source.component, set())}
    _reject_loops(names, direct, scenario_file)
    remaining = list(names)
    incoming = {n: {a for a, b in edges if b == n} for n in names}
    order: list[str] = []
    while remaining:
        ready = [n for n in remaining if not (incoming[n] & set(remaining))]
        pick = ready[0] if ready else remaining[0]  # a cycle: the first listed goes first
        order.append(pick)
        remaining.remove(pick)
    return order


def _reject_loops(names: list[str], direct: set[tuple[str, str]], scenario_file: str | None) -> None:
    state: dict[str, int] = {}

    def visit(n: str, path: list[str]) -> None:
        if state.get(n) == 2:
            return
        if state.get(n) == 1:
            cycle = path[path.index(n):] + [n]
            raise InputError(f"algebraic loop: {' -> '.join(cycle)} (every output in it is declared to depend "
                             "directly on an input); such a cycle cannot be ordered: break it or use "
                             "run.coupling = \"jacobi\"", file=scenario_file, where="wiring.connections")
        state[n] = 1
        for a, b in sorted(direct):
            if a == n:
                visit(b, path + [n])
        state[n] = 2

    for n in names:
        visit(n, [])
