"""The plant inside an SSP: a component whose FMU is fishfmu's plant FMU (``fishfmu export-fmu``, as
``fishfmu export-ssp`` puts it in an archive) stands for the scenario's plant.

Its connections become the plant's links (``plant.<id>.<signal>``, as the FMU's variables are named).  Run as a
scenario itself (``fishfmu run line.ssp``), the archive gives the whole scenario: ``[run]``, ``[line]``, ``[fish]``,
``[plant]`` and ``[kpi]`` from the plant FMU's ``resources/scenario.toml`` (what that FMU simulates), the run's
length from the SSD's default experiment, ``run.seed`` and ``fish.count`` from the plant component's parameter values
``seed`` and ``fish_count``, a value for one of its inputs as a constant in ``[wiring] inputs``; the other components
join ``[[fmu]]`` and the connections ``[wiring]`` as for any ``[system] ssp``.  Named as ``[system] ssp`` of a
scenario file, the file's own tables are the plant, and the plant component's values must agree with them.
"""

from __future__ import annotations

import tomllib
import zipfile
from pathlib import Path
from typing import Any

from lxml import etree

from plant.errors import InputError

from fishfmu.fmu.archive import MAX_MEMBERS, MAX_UNPACKED_BYTES, check_members, open_regular_file
from fishfmu.scenario.ssp import MAX_XML_BYTES, SspComponent, SspSystem

PLANT_COMPONENT = "plant"
"""The plant's component name in an archive ``fishfmu export-ssp`` writes."""
PLANT_FILE = "resources/fishfmu_plant.fmu"
PLANT_MODEL = "FishfmuPlant"
"""The plant FMU's modelIdentifier (:class:`fishfmu.cosim.plant_fmu_slave.FishfmuPlant`)."""
SCENARIO_MEMBER = "resources/scenario.toml"
PLANT_PARAMETERS = {"seed": ("run", "seed"), "fish_count": ("fish", "count")}
PLANT_TABLES = ("run", "line", "fish", "plant", "kpi")


def plant_scenario(fmu: Path) -> dict[str, Any] | None:
    """The scenario inside a fishfmu plant FMU (its run, line, fish, plant and kpi tables); None for any other FMU,
    a broken one included (reading it as a component then says what is wrong with it, naming the component)."""
    try:
        return _plant_scenario(fmu)
    except zipfile.BadZipFile:
        return None


def _plant_scenario(fmu: Path) -> dict[str, Any] | None:
    with open_regular_file(fmu) as fh, zipfile.ZipFile(fh) as zf:
        check_members(fmu, zf, MAX_UNPACKED_BYTES, MAX_MEMBERS)
        names = set(zf.namelist())
        if "modelDescription.xml" not in names or SCENARIO_MEMBER not in names:
            return None
        with zf.open("modelDescription.xml") as md:
            try:
                root = etree.fromstring(md.read(MAX_XML_BYTES), etree.XMLParser(resolve_entities=False,
                                                                                 no_network=True))
            except etree.XMLSyntaxError:
                return None  # not a plant FMU's: the component's own reading reports it
        cs = root.find("CoSimulation")
        if cs is None or cs.get("modelIdentifier") != PLANT_MODEL:
            return None
        with zf.open(SCENARIO_MEMBER) as doc:
            try:
                return tomllib.loads(doc.read(MAX_XML_BYTES).decode("utf-8"))
            except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
                raise InputError(f"the plant FMU's {SCENARIO_MEMBER} is not valid TOML: {exc}", file=fmu) from None


def plant_component(system: SspSystem, ssp: Path) -> tuple[SspComponent, dict[str, Any]] | None:
    """The one fishfmu plant component of ``system`` and its scenario, or None."""
    found = [(c, doc) for c in system.components if (doc := plant_scenario(c.fmu)) is not None]
    if len(found) > 1:
        raise InputError(f"components {', '.join(c.name for c, _ in found)} are all fishfmu plant FMUs; a system has "
                         "one plant", file=ssp)
    return found[0] if found else None


def plant_links(system: SspSystem, plant: SspComponent) -> list[tuple[str, str]]:
    """The system's connections as (source, target), the plant component's ends named ``plant.<port>``."""
    def end(name: str) -> str:
        comp, _, var = name.partition(".")
        return f"{PLANT_COMPONENT}.{var}" if comp == plant.name else name
    return [(end(c.source), end(c.target)) for c in system.connections]


def plant_inputs(plant: SspComponent) -> dict[str, Any]:
    """The plant component's values other than seed and fish_count: constants of its inputs (``plant.<port>``)."""
    return {f"{PLANT_COMPONENT}.{k}": v for k, v in plant.parameters.items() if k not in PLANT_PARAMETERS}


def scenario_data(ssp: Path, system: SspSystem) -> dict[str, Any]:
    """The scenario an SSP with a fishfmu plant component is, as TOML data (before validation)."""
    found = plant_component(system, ssp)
    if found is None:
        raise InputError("has no fishfmu plant component (an FMU made by `fishfmu export-fmu`), so it is not a whole "
                         "line: name it as [system] ssp of a scenario file that has the line instead", file=ssp)
    plant, doc = found
    data = {k: doc[k] for k in PLANT_TABLES if k in doc}
    for key, (table, field) in PLANT_PARAMETERS.items():
        if key in plant.parameters:
            data.setdefault(table, {})[field] = plant.parameters[key]
    if system.stop_time_s is not None:
        data.setdefault("run", {})["duration_s"] = system.stop_time_s
    data["system"] = {"ssp": str(ssp)}
    if plant_inputs(plant):
        data["wiring"] = {"inputs": plant_inputs(plant)}
    return data


def check_plant_agrees(plant: SspComponent, seed: int, fish_count: int, inputs: dict[str, Any], ssp: Path,
                       scenario_file: Path) -> None:
    """A plant component in a scenario file's ``[system] ssp``: its values must be the file's own."""
    own = {"seed": seed, "fish_count": fish_count}
    for key, value in plant.parameters.items():
        want = own[key] if key in own else inputs.get(f"{PLANT_COMPONENT}.{key}")
        if want != value:
            where = {"seed": "run.seed", "fish_count": "fish.count"}.get(key, f"wiring.inputs.{PLANT_COMPONENT}.{key}")
            raise InputError(f"component '{plant.name}' of {ssp.name} (the plant) gives {key} = {value}, the scenario "
                             f"{where} = {want}; the scenario file's plant is the one run, so they must agree",
                             file=scenario_file, where="system.ssp")
