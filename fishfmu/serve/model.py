"""The served line's information model, made once from the scenario: what the OPC UA address space holds and what
the signal list (``fishfmu signal-list``) gives a PLC's tag table.

One object per component: ``plant`` holds an object per conveyor, photo-eye, camera and device of the ``[line]``
table with its ports (:data:`plant.sim.ports.SIGNALS`: type, unit, description) and its parameters from the line
table (positions, lengths, latencies, strokes: every number the table gives, read-only, described by the line
contract's own field descriptions); each FMU instance is an object holding its served variables, described by its
modelDescription.  A value that is a code is an enumeration (its values and texts); a Boolean has the texts of
its two states.  Node ids stay the signal names of the scenario (``plant.cam.lead_x``, ``drive_c1.belt_speed``).

**Which twin a PLC reads.**  A plant output wired to an FMU input appears twice: as the plant's port
(``plant.cam.lead_x``: the value now, after the last step) and under the FMU as that FMU's input
(``controller.cam_lead_x``: what the FMU was sent in the last step, one step older).  A PLC reads the plant's; the
FMU's input says so in its description.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from plant.contract.kpis import KPIS as KPI_TABLE
from plant.contract.line import Camera, Conveyor, Device, Line, PhotoEye
from plant.contract.plausibility import MAX_BELT_SPEED_MPS
from plant.sim.ports import PlantPorts, signal_of

from fishfmu.scenario.wiring import PLANT

if TYPE_CHECKING:
    from fishfmu.cosim.build import CheckedScenario

NAMESPACE = "urn:fishfmu"
UNECE = {"m": "MTR", "m/s": "MTS", "s": "SEC", "N": "NEW", "kg": "KGM", "rpm": "RPM", "1/min": "RPM",
         "rad/s": "2A", "A": "AMP", "V": "VLT", "W": "WTT", "Hz": "HTZ", "K": "KEL", "degC": "CEL", "deg": "DD"}
"""UNECE Recommendation 20 codes for the units the line uses (OPC UA Part 8, EUInformation.UnitId)."""
ROOT = "fishfmu"
KPIS = "fishfmu.kpis"
"""The object holding the run's KPIs once it has ended."""
"""The root object under Objects: the line's components, its status and its methods."""

IN, OUT, PARAMETER, STATUS = "in", "out", "parameter", "status"
"""Directions: a client writes it; the line writes it; fixed for the run; the run's own state."""

_UNIT_SUFFIXES = {"_mps": "m/s", "_m": "m", "_s": "s", "_hz": "Hz", "_deg": "deg", "_n": "N", "_kg": "kg"}
"""A line-table field's unit from its name's suffix (the contract names every unit so)."""

_TWO_STATES = {"blocked": ("blocked", "clear"), "double": ("double in view", "no double"),
               "lead_double": ("lead fish is a double", "lead fish single"), "command": ("to end", "home"),
               "at_home": ("home", "not home"), "at_end": ("at end", "not at end")}
"""A Boolean port's texts for true and false."""

_ENUMERATIONS = {"lead_heading": ((-1, "tail first"), (0, "no fish"), (1, "head first"))}
"""A port whose value is a code: its values and what each means."""

_KINDS = {Conveyor: "conveyor", PhotoEye: "photo-eye", Camera: "camera", Device: "device"}


@dataclass(frozen=True)
class Component:
    """An object in the address space."""

    key: str
    """Its node id (``plant.c1``, ``drive_c1``)."""
    parent: str
    name: str
    kind: str
    description: str


@dataclass(frozen=True)
class Item:
    """A variable of a component: a signal, a parameter or the run's status."""

    key: str
    """Its node id and the name a scenario gives it (``plant.cam.lead_x``)."""
    component: str
    name: str
    type: str
    """FMI type: Real, Integer, Boolean or String."""
    unit: str | None
    range: tuple[float, float] | None
    direction: str
    description: str
    two_states: tuple[str, str] | None = None
    enumeration: tuple[tuple[int, str], ...] | None = None
    value: Any = None
    """A parameter's value."""


@dataclass(frozen=True)
class InformationModel:
    components: list[Component]
    items: list[Item]

    def item(self, key: str) -> Item:
        return next(i for i in self.items if i.key == key)


STATUS_ITEMS = [
    Item("fishfmu.time_s", ROOT, "time_s", "Real", "s", None, STATUS, "simulated time of the line"),
    Item("fishfmu.run_state", ROOT, "run_state", "String", None, None, STATUS,
         "the run's state: waiting (for start()), running, paused, finished, stopped or failed: <why>; each change "
         "is an event from this object"),
    Item("fishfmu.lag_s", ROOT, "lag_s", "Real", "s", None, STATUS,
         "real time: how late the last step started against the wall clock (0 in lockstep)"),
    Item("fishfmu.lag_max_s", ROOT, "lag_max_s", "Real", "s", None, STATUS,
         "real time: the largest lag since the run (re)started"),
    Item("fishfmu.late_steps", ROOT, "late_steps", "Integer", None, None, STATUS,
         "real time: steps that started more than one communication step (of wall time) late"),
    Item("fishfmu.realtime_factor", ROOT, "realtime_factor", "Real", None, None, STATUS,
         "the real-time factor paced to (set_speed changes it; 0 in lockstep)"),
    Item("fishfmu.realtime_factor_reached", ROOT, "realtime_factor_reached", "Real", None, None, STATUS,
         "simulated time per second of wall time while running, since the run (re)started"),
    *(Item(k, ROOT, k.partition(".")[2], "Integer", None, None, STATUS, text) for k, text in (
        ("fishfmu.fish_waiting", "fish of the batch not yet dropped onto the line"),
        ("fishfmu.fish_on_line", "fish on the line"),
        ("fishfmu.fish_left", "fish that left at the outfeed"),
        ("fishfmu.fish_rejected", "fish a device took off the line"))),
    *(Item(f"{KPIS}.{k.key}", KPIS, k.key, "Real", k.unit, None, STATUS,
           f"{k.description} (once the run has finished; NaN before, or when undefined)")
      for k in KPI_TABLE)]
"""The run's own variables on the root object."""

METHODS = {"step": ("n: Int32 -> time_s: Double", "lockstep only: advance n communication steps; the new time"),
           "start": ("", "start a run waiting for it (--wait-for-start)"),
           "pause": ("", "pause a running run (real time: the wall clock no longer steps it; lockstep: step() is "
                     "refused)"),
           "resume": ("", "resume a paused run"),
           "stop": ("", "end the run; it is written like any run, and the server ends"),
           "reset": ("[seed: UInt32] -> time_s: Double", "start the run over from the scenario's start, with the "
                     "scenario's seed or the one given"),
           "set_speed": ("factor: Double", "real time only: pace to this real-time factor from now on (0.001 to "
                         "1000)")}
"""The root object's methods: their arguments and what they do."""


def served_signals(checked: CheckedScenario, names: list[str]) -> list[str]:
    """Every signal in the address space: the run's signals ``names``, then the plant's outputs it does not record
    (a PLC always needs its sensors)."""
    plant_outputs = [f"{PLANT}.{port}" for port in PlantPorts.of(checked.scenario.line).outputs()]
    return [*names, *(k for k in plant_outputs if k not in names)]


def variable_type(item: Item) -> str:
    """The OPC UA VariableType of an item (a name in namespace 0)."""
    if item.direction == PARAMETER:
        return "PropertyType"
    if item.enumeration:
        return "MultiStateValueDiscreteType"
    if item.two_states:
        return "TwoStateDiscreteType"
    if item.type == "Real":  # with a range an AnalogItemType (EURange mandatory), else its base type
        return "AnalogItemType" if item.range is not None else "BaseAnalogType"
    return "BaseDataVariableType"


def _unit_of_field(name: str) -> str | None:
    return next((u for suffix, u in _UNIT_SUFFIXES.items() if name.endswith(suffix)), None)


def _parameters(entry: Any, key: str) -> list[Item]:
    """A line-table entry's numbers and words as read-only items (its id is the object's name)."""
    out = []
    for name, info in type(entry).model_fields.items():
        value = getattr(entry, name)
        if name == "id" or value is None or not isinstance(value, (int, float, str)):
            continue
        kind = ("Boolean" if isinstance(value, bool) else "String" if isinstance(value, str)
                else "Integer" if isinstance(value, int) else "Real")
        out.append(Item(f"{key}.{name}", key, name, kind, _unit_of_field(name), None, PARAMETER,
                        f"{info.description or name} (from the scenario's [line] table)", value=value))
    return out


def _port_range(port: str, entry: Any) -> tuple[float, float] | None:
    """The range a plant port's values take in operation, from the line table."""
    signal = signal_of(port).name
    if signal == "speed":
        return (-MAX_BELT_SPEED_MPS, MAX_BELT_SPEED_MPS)
    if signal == "position":
        return (0.0, 1.0)
    if signal == "lead_x":  # clipped to the field of view (plus the camera's noise)
        return (entry.x_start_m, entry.x_end_m)
    if signal == "lead_length":
        return (0.0, entry.x_end_m - entry.x_start_m)
    return None


def _port_item(key: str, component: str, entry: Any, direction: str, fed: list[str]) -> Item:
    s = signal_of(key)
    text = s.description[0].upper() + s.description[1:]
    if fed:
        text += f"; feeds {', '.join(fed)}"
    return Item(key, component, s.name, s.type, s.unit, _port_range(key, entry), direction, text,
                _TWO_STATES.get(s.name, ("true", "false")) if s.type == "Boolean" else None, _ENUMERATIONS.get(s.name))


def _fmu_item(key: str, checked: CheckedScenario, direction: str, source: str | None, fed: list[str]) -> Item:
    comp, _, var = key.partition(".")
    opened = checked.opened[comp]
    v = opened.variables[var]
    md = next((m for m in opened.model_description.modelVariables if m.name == var), None)
    lo, hi = getattr(md, "min", None), getattr(md, "max", None)
    declared = getattr(md, "declaredType", None)
    items = getattr(declared, "items", None) or []
    lo = lo if lo is not None else getattr(declared, "min", None)
    hi = hi if hi is not None else getattr(declared, "max", None)
    rng = (float(lo), float(hi)) if lo is not None and hi is not None and v.type in ("Real", "Integer") else None
    text = (getattr(md, "description", None) or var).rstrip(".")
    text = f"{text} ({getattr(md, 'causality', None) or 'variable'} of FMU '{comp}')"
    if source is not None:
        text += (f"; fed from {source}: the value sent in the last step, one step older than {source}, "
                 f"which a PLC reads" if source.startswith(f"{PLANT}.") else f"; fed from {source}")
    if fed:
        text += f"; feeds {', '.join(fed)}"
    if direction == IN:
        text += "; written by clients ([opcua] inputs)"
    enumeration = tuple((int(i.value), f"{i.name}" + (f": {i.description}" if i.description else ""))
                        for i in items) or None
    if source is not None and source.startswith(f"{PLANT}.") and v.type in ("Boolean", "Integer"):
        port = signal_of(source).name  # the texts of the plant port it is a copy of
        enumeration = enumeration or _ENUMERATIONS.get(port)
        two_states = _TWO_STATES.get(port)
    else:
        two_states = None
    return Item(key, comp, var, v.type, v.unit, rng, direction, text,
                (two_states or ("true", "false")) if v.type == "Boolean" else None, enumeration)


def information_model(checked: CheckedScenario, served: list[str], status: list[Item]) -> InformationModel:
    """The model of a checked scenario (:class:`fishfmu.cosim.build.CheckedScenario`) serving the signals
    ``served`` (see :func:`fishfmu.serve.address_space.served_signals`), with the run's ``status`` items."""
    line: Line = checked.scenario.line
    wiring = checked.wiring
    external = set(wiring.external)
    source_of = {c.target.key: c.source.key for c in wiring.connections}
    fed: dict[str, list[str]] = {}
    for c in wiring.connections:
        fed.setdefault(c.source.key, []).append(c.target.key)

    components = [Component(PLANT, ROOT, PLANT, "plant", "The line's physics: its conveyors, photo-eyes, cameras "
                            "and devices, each an object with its ports and its [line] parameters")]
    items: list[Item] = []
    entries = {e.id: e for group in (line.conveyors, line.photoeyes, line.cameras, line.devices) for e in group}
    plant_ports = PlantPorts.of(line)
    plant_keys = {f"{PLANT}.{p}" for p in plant_ports.inputs() + plant_ports.outputs()}
    for eid, entry in entries.items():
        key = f"{PLANT}.{eid}"
        kind = _KINDS[type(entry)]
        if isinstance(entry, Device):
            kind = entry.kind
        components.append(Component(key, PLANT, eid, kind, f"{kind} '{eid}' of the line"))
        items += _parameters(entry, key)
    for f in checked.scenario.fmu:
        md = checked.opened[f.name].model_description
        text = (md.description or md.modelName or f.name).rstrip(".")
        components.append(Component(f.name, ROOT, f.name, "fmu", f"FMU instance '{f.name}': {text}"))
    for key in served:
        comp, _, _ = key.partition(".")
        direction = IN if key in external else OUT
        if comp == PLANT and key in plant_keys:
            eid = key[len(PLANT) + 1:].rpartition(".")[0]
            items.append(_port_item(key, f"{PLANT}.{eid}", entries[eid], direction, fed.get(key, [])))
        else:
            items.append(_fmu_item(key, checked, direction, source_of.get(key), fed.get(key, [])))
    order = {c.key: i for i, c in enumerate(components)}
    items.sort(key=lambda i: order[i.component])  # stable: each component's items together, in their order
    root = Component(ROOT, "", ROOT, "line", "The served line: its components, the run's status and the methods "
                     "that drive it")
    kpis = Component(KPIS, ROOT, "kpis", "kpis", "The run's KPIs, served once the run has ended")
    return InformationModel([root, kpis, *components], [*status, *items])
