"""``fishfmu export-ssp``: a scenario's system as an SSP 1.0 archive (System Structure and Parameterization, Modelica
Association) for other tools.

The archive holds ``SystemStructure.ssd`` (one system: every FMU of the scenario and the plant as components, each
with its connectors: causality, type and unit; the scenario's connections with their gain and offset as
``ssc:LinearTransformation``; the units in ``ssd:Units``; the run's duration as ``ssd:DefaultExperiment``), one
``.ssv`` parameter set per component that has values, bound to it, and the FMUs under ``resources/``: each built-in
FMU as ``fishfmu build-fmus`` makes it (one file for all its instances), the plant as ``fishfmu export-fmu`` makes it
(component ``plant``, its connectors named as the wiring names the plant's ports), a user's FMU byte for byte.

What SSP cannot say is listed, never dropped without a word: :func:`not_in_ssp` names each such part of the scenario,
the command prints the list and the archive carries it as :data:`NOTES_NAME`.  The comm step goes into an OSP
annotation of the default experiment too (libcosim reads it as its step size; other tools ignore it); fishfmu's own
run settings, line, fish and KPI settings travel inside the plant FMU (its ``resources/scenario.toml``), which is how
``fishfmu run line.ssp`` reads them back (:mod:`fishfmu.scenario.ssp_plant`).

Units: a connector carries its variable's unit where the FMU (or the plant's port table) defines it in SI base units;
a unit without a definition is left off the connector and listed.  A gain between two different units is written
as the factor fishfmu applies to the raw values (``target = factor x source + offset``), listed too: the standard
also lets a tool convert between the connectors' units.
"""

from __future__ import annotations

import io
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lxml import etree

from plant.errors import InputError
from plant.sim.ports import PlantPorts, signal_of

from fishfmu.cosim.plant_fmu import export_plant_fmu
from fishfmu.cosim.preflight import describe_file
from fishfmu.fmu.archive import BASE_UNITS, FmuVariable
from fishfmu.fmu.build import builtin_fmu
from fishfmu.scenario.ssp import NS
from fishfmu.scenario.ssp_plant import PLANT_COMPONENT, PLANT_FILE
from fishfmu.scenario.schema import Scenario

NOTES_NAME = "resources/fishfmu-not-in-ssp.txt"
"""The archive member listing what SSP cannot say about the scenario."""
OSP_NS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed member times: the same scenario gives the same SSD and SSV bytes
SSC_TYPES = {"Real": "Real", "Integer": "Integer", "Boolean": "Boolean", "String": "String",
             "Enumeration": "Enumeration"}
KINDS = ("input", "output", "parameter", "calculatedParameter")


@dataclass(frozen=True)
class Exported:
    """What ``export_ssp`` wrote: the archive's members and what SSP cannot say."""

    members: dict[str, bytes]
    not_in_ssp: list[str]


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _xml(root: Any) -> bytes:
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _number(value: float) -> str:
    """A double as the shortest text that reads back to the same bits."""
    return repr(float(value))


def _value_element(parent: Any, var: FmuVariable | None, value: Any) -> bool:
    """Append the typed ``ssv:`` value of ``value`` for ``var``; False where SSV 1.0 cannot hold it here."""
    kind = var.type if var is not None else ("Boolean" if isinstance(value, bool) else
                                              "Integer" if isinstance(value, int) else
                                              "String" if isinstance(value, str) else "Real")
    if kind == "Real":
        text = _number(value)
    elif kind == "Integer" and not isinstance(value, bool) and float(value) == int(value):
        text = str(int(value))
    elif kind == "Boolean":
        text = "true" if value else "false"
    elif kind == "String":
        text = str(value)
    else:  # Enumeration (SSV names the item, fishfmu gives its number), Binary, arrays
        return False
    etree.SubElement(parent, _q("ssv", kind), value=text)
    return True


def parameter_set(name: str, values: dict[str, Any], variables: dict[str, FmuVariable], owner: str,
                  notes: list[str]) -> bytes | None:
    """An SSV parameter set of ``values`` (typed by the FMU's variables); None when none can be written."""
    root = etree.Element(_q("ssv", "ParameterSet"), nsmap={"ssv": NS["ssv"]}, version="1.0", name=name)
    params = etree.SubElement(root, _q("ssv", "Parameters"))
    for key, value in values.items():
        p = etree.Element(_q("ssv", "Parameter"), name=key)
        if _value_element(p, variables.get(key), value):
            params.append(p)
        else:
            notes.append(f"{owner}.{key} = {value!r}: a {variables[key].type} value, which fishfmu gives as a number "
                         "and SSV 1.0 names otherwise; not in the archive")
    return _xml(root) if len(params) else None


def _connector(parent: Any, name: str, kind: str, type_: str, unit: str | None) -> None:
    c = etree.SubElement(parent, _q("ssd", "Connector"), name=name, kind=kind)
    typed = etree.SubElement(c, _q("ssc", SSC_TYPES[type_]))
    if unit is not None and type_ == "Real":
        typed.set("unit", unit)


def _units_element(units: dict[str, tuple[float, ...]]) -> Any:
    el = etree.Element(_q("ssd", "Units"))
    for name, base in sorted(units.items()):
        u = etree.SubElement(el, _q("ssc", "Unit"), name=name)
        attrs = {k: str(int(e)) for k, e in zip(BASE_UNITS, base) if e}
        if base[len(BASE_UNITS)] != 1.0:
            attrs["factor"] = _number(base[len(BASE_UNITS)])
        if base[len(BASE_UNITS) + 1] != 0.0:
            attrs["offset"] = _number(base[len(BASE_UNITS) + 1])
        etree.SubElement(u, _q("ssc", "BaseUnit"), **attrs)
    return el


def _plant_variables(sc: Scenario, plant_fmu: Path) -> dict[str, FmuVariable]:
    """The plant FMU's variables with the units of the plant's port table (the FMU states them in words only)."""
    out = {}
    ports = set(PlantPorts.of(sc.line).inputs()) | set(PlantPorts.of(sc.line).outputs())
    for name, v in describe_file(plant_fmu).variables.items():
        s = signal_of(name) if name in ports else None
        out[name] = FmuVariable(v.name, v.causality, v.type, v.variability, v.value_reference,
                                s.unit if s else v.unit, v.start, s.unit_base if s else v.unit_base,
                                v.initial, v.fmi_type)
    return out


def _fmu_files(sc: Scenario, plant_fmu: Path) -> tuple[dict[str, tuple[str, Path]], dict[str, bytes]]:
    """Each component's FMU: its name in the archive and its file; and the archive's FMU members (one per distinct
    file: the built-in FMUs under their names, a user's under its file name, or its component's folder when another
    file has that name)."""
    sources: dict[str, tuple[str, Path]] = {}
    members: dict[str, bytes] = {}
    by_content: dict[bytes, str] = {}
    for f in sorted(sc.fmu, key=lambda f: f.builtin is None):  # the built-in ones take their names first
        path = builtin_fmu(f.builtin) if f.builtin else Path(f.path)
        data = path.read_bytes()
        if data not in by_content:
            member = f"resources/{f.builtin}.fmu" if f.builtin else f"resources/{path.name}"
            if member in members:
                member = f"resources/{f.name}/{path.name}"
            members[member], by_content[data] = data, member
        sources[f.name] = (by_content[data], path)
    members[PLANT_FILE] = plant_fmu.read_bytes()
    sources[PLANT_COMPONENT] = (PLANT_FILE, plant_fmu)
    order = [f.name for f in sc.fmu] + [PLANT_COMPONENT]  # components in the scenario's order
    return {name: sources[name] for name in order}, members


def not_in_ssp(sc: Scenario) -> list[str]:
    """The parts of the scenario an SSP 1.0 system structure cannot say, one line each."""
    notes = []
    for e in sc.event:
        value = "" if e.value is None else f" {e.value}"
        notes.append(f"[[event]] at {e.t_s} s: {e.action} {e.target}{value} (SSP has no events)")
    for key, b in sc.expect.items():
        bounds = ", ".join(f"{k} = {v}" for k, v in b.model_dump(exclude_none=True, exclude_defaults=True).items())
        notes.append(f"[expect] {key}: {bounds} (SSP has no acceptance bounds)")
    if sc.record.variables:
        notes.append(f"[record] variables = {sc.record.variables} (SSP says nothing of what a run records)")
    if sc.opcua.inputs:
        notes.append(f"[opcua] inputs = {sc.opcua.inputs}: written by a PLC when served; in the SSP these inputs "
                     "keep their start values")
    for conveyor, signal in sc.wiring.setpoints.items():
        notes.append(f"[wiring] setpoints {conveyor} = {signal}: which signal belts.csv logs (not a connection)")
    for c in sc.connection_specs():
        if c.round:
            notes.append(f"{c.where}: round = true (Real into Integer, rounded) has no SSP transformation; another "
                         "tool converts as it does")
    for part in sc.line.parts:  # export-fmu carries the file in the plant FMU; fishfmu's read-back does not unpack it
        notes.append(f"[[line.parts]] stl = {part.stl}: carried inside the plant FMU (resources/parts/); reading the "
                     "archive back as a scenario (fishfmu run line.ssp) does not unpack it: run the scenario itself")
    for f in sc.fmu:
        if f.step_multiple != 1:
            notes.append(f"fmu '{f.name}': step_multiple = {f.step_multiple} (SSP 1.0 has no per-component step)")
    r = sc.run
    notes.append(f"[run] comm_step_s = {r.comm_step_s}, coupling = {r.coupling}, stop_when_clear = "
                 f"{str(r.stop_when_clear).lower()}, fmu_process = {r.fmu_process}: how fishfmu's master runs; SSP 1.0 "
                 "has no master settings (the step is also in the OSP annotation libcosim reads); all [run], [line], "
                 "[fish], [plant] and [kpi] settings travel in the plant FMU (resources/scenario.toml), which "
                 "`fishfmu run` of the archive reads back")
    notes.append(f"run.seed = {r.seed} and fish.count = {sc.fish.count}: the plant component's parameters seed and "
                 "fish_count (its SSV); run.duration_s: DefaultExperiment stopTime")
    notes.append("KPIs (contracts/kpis.md) are fishfmu's: another tool runs the system but computes none")
    return notes


def export_ssp(sc: Scenario, work: Path) -> Exported:
    """The SSP archive's members for ``sc``; ``work``: a temporary folder (the plant FMU is built there)."""
    plant_fmu = export_plant_fmu(sc, work)
    sources, members = _fmu_files(sc, plant_fmu)
    variables = {name: (_plant_variables(sc, path) if name == PLANT_COMPONENT else describe_file(path).variables)
                 for name, (_, path) in sources.items()}
    notes = not_in_ssp(sc)
    values: dict[str, dict[str, Any]] = {f.name: dict(f.parameters) for f in sc.fmu}
    values[PLANT_COMPONENT] = {"seed": sc.run.seed, "fish_count": sc.fish.count}
    for key, value in sc.wiring.inputs.items():  # a constant input is its start value, never set by the master
        comp, _, var = key.partition(".")
        values[comp][var] = value

    root = etree.Element(_q("ssd", "SystemStructureDescription"), nsmap={**{k: NS[k] for k in ("ssd", "ssc", "ssv")}, "osp": OSP_NS},
                         version="1.0", name=sc.run.name, generationTool="fishfmu export-ssp")
    system = etree.SubElement(root, _q("ssd", "System"), name=sc.run.name)
    elements = etree.SubElement(system, _q("ssd", "Elements"))
    units: dict[str, tuple[float, ...]] = {}
    for name, (member, _) in sources.items():
        comp = etree.SubElement(elements, _q("ssd", "Component"), name=name, type="application/x-fmu-sharedlibrary",
                                source=member, implementation="CoSimulation")
        connectors = etree.SubElement(comp, _q("ssd", "Connectors"))
        for v in variables[name].values():
            if v.causality not in KINDS or v.type not in SSC_TYPES:
                continue  # locals, independent time; Binary, Clock and array variables fishfmu connects to nothing
            unit = v.unit if v.unit and v.unit_base else None
            if v.unit and not v.unit_base and v.type == "Real":
                notes.append(f"{name}.{v.name}: unit '{v.unit}' has no definition in its FMU; left off its connector")
            if unit:
                units[unit] = v.unit_base
            _connector(connectors, v.name, v.causality, v.type, unit)
        ssv = parameter_set(name, values.get(name, {}), variables[name], name, notes)
        if ssv is not None:
            members[f"resources/{name}.ssv"] = ssv
            bindings = etree.SubElement(comp, _q("ssd", "ParameterBindings"))
            etree.SubElement(bindings, _q("ssd", "ParameterBinding"), source=f"resources/{name}.ssv")
    connections = etree.SubElement(system, _q("ssd", "Connections"))
    for c in sc.connection_specs():
        (a, va), (b, vb) = c.source, c.target
        el = etree.SubElement(connections, _q("ssd", "Connection"), startElement=a, startConnector=va, endElement=b,
                              endConnector=vb)
        if c.gain is not None or c.offset is not None:
            etree.SubElement(el, _q("ssc", "LinearTransformation"), factor=_number(1.0 if c.gain is None else c.gain),
                             offset=_number(0.0 if c.offset is None else c.offset))
            ua, ub = variables[a][va].unit, variables[b][vb].unit
            if ua and ub and ua != ub:
                notes.append(f"{c.where}: factor {c.gain} converts {ua} to {ub} on the raw values, as fishfmu applies "
                             "it; a tool that also converts by the connectors' units would convert twice")
    if units:
        root.append(_units_element(units))
    experiment = etree.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0",
                                  stopTime=_number(sc.run.duration_s))
    annotation = etree.SubElement(etree.SubElement(experiment, _q("ssd", "Annotations")), _q("ssc", "Annotation"),
                                  type="com.opensimulationplatform")
    # the namespace is declared on the root: libcosim reads any attribute of Algorithm as an unknown algorithm
    algorithm = etree.SubElement(annotation, f"{{{OSP_NS}}}Algorithm")
    etree.SubElement(algorithm, f"{{{OSP_NS}}}FixedStepAlgorithm", baseStepSize=_number(sc.run.comm_step_s))
    members["SystemStructure.ssd"] = _xml(root)
    members[NOTES_NAME] = ("What this SSP cannot say about the scenario it was exported from (fishfmu export-ssp):\n"
                           + "".join(f"- {n}\n" for n in notes)).encode()
    return Exported(members, notes)


def ssp_bytes(exported: Exported) -> bytes:
    """The archive: SystemStructure.ssd first, then the other members by name, each with a fixed time."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(exported.members, key=lambda n: (n != "SystemStructure.ssd", n)):
            zf.writestr(zipfile.ZipInfo(name, _ZIP_TIME), exported.members[name], zipfile.ZIP_DEFLATED)
    return buf.getvalue()


def write_ssp(sc: Scenario) -> tuple[bytes, list[str]]:
    """The SSP archive of ``sc`` as bytes, and what SSP cannot say of it."""
    if any(f.name == PLANT_COMPONENT for f in sc.fmu):  # the schema reserves it; kept here as the archive relies on it
        raise InputError(f"an FMU is named '{PLANT_COMPONENT}', the plant component's name")
    with tempfile.TemporaryDirectory(prefix="fishfmu-export-ssp-") as tmp:
        exported = export_ssp(sc, Path(tmp))
        return ssp_bytes(exported), exported.not_in_ssp
