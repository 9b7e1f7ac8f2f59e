"""The plant's ports are declared once (plant.sim.ports) and everything that names them agrees with that
declaration: the plant's outputs, a scenario's wiring, the co-simulation's values and the plant FMU's
variables (no Exudyn step needed: the plant FMU builds its plant only at initialisation)."""

from __future__ import annotations

from pathlib import Path

import pytest

from plant.sim.ports import SIGNALS, PlantPorts, signal_of
from plant.sim.state import PlantOutputs

from fishfmu.cosim.plant_fmu import PlantInFmu
from fishfmu.scenario.schema import load_scenario
from fishfmu.scenario.wiring import PLANT, plant_ports

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_test.toml"


@pytest.fixture(scope="module")
def line():
    return load_scenario(PAPER).line


def test_the_declaration_names_every_conveyors_and_photoeyes_ports_in_the_lines_order(line):
    ports = PlantPorts.of(line)
    conveyors = [c.id for c in line.conveyors]
    beams = [p.id for p in line.photoeyes]
    assert ports.inputs() == [f"{c}.speed" for c in conveyors]
    assert ports.outputs() == ([f"{c}.{s}" for c in conveyors for s in ("speed", "load_force", "load_mass")]
                               + [f"{p}.blocked" for p in beams])
    assert ports.outputs(["blocked"]) == [f"{p}.blocked" for p in beams]
    with pytest.raises(KeyError):
        signal_of("c1.torque")


def test_the_plants_outputs_are_its_declared_output_ports(line):
    ports = PlantPorts.of(line)
    at_rest = PlantOutputs.at_rest(ports).port_values()
    assert list(at_rest) == ports.outputs()
    assert all(type(v) is (bool if signal_of(k).type == "Boolean" else float) for k, v in at_rest.items())


def test_the_wiring_knows_the_declared_ports_with_their_types_and_units(line):
    ports = PlantPorts.of(line)
    wired = plant_ports(line)
    assert list(wired) == ports.outputs()
    for name, candidates in wired.items():
        s = signal_of(name)
        assert [p.causality for p in candidates] == (["input", "output"] if name in ports.inputs() else ["output"])
        assert all(p.component == PLANT and p.type == s.type and p.unit == s.unit and p.unit_base == s.unit_base
                   for p in candidates)


def with_every_kind(tmp_path: Path) -> Path:
    """The paper's scenario with a camera and a pusher over its last belt: a line with every kind of port."""
    text = PAPER.read_text()
    at = text.index("[[line.photoeyes]]")
    scenario = tmp_path / "camera.toml"
    scenario.write_text(text[:at] + '[[line.cameras]]\nid = "cam"\nx_start_m = 5.2\nx_end_m = 6.1\n\n'
                        + '[[line.devices]]\nid = "pusher"\nkind = "pusher"\nx_m = 5.5\nlength_m = 0.8\n\n' + text[at:])
    return scenario


def test_the_plant_fmu_has_the_declared_ports_as_variables(tmp_path):
    scenario = with_every_kind(tmp_path)
    line = load_scenario(scenario).line
    ports = PlantPorts.of(line)
    logged: list[str] = []
    fmu = PlantInFmu(scenario, logged.append)
    assert fmu.input_names == ports.inputs()
    plant_outputs = [n for n in fmu.output_names if n not in PlantInFmu.counts]
    assert sorted(plant_outputs) == sorted(set(ports.outputs()) - set(ports.inputs()))
    assert {n: fmu.units.get(n) for n in fmu.input_names + plant_outputs} == {
        n: signal_of(n).unit for n in fmu.input_names + plant_outputs}
    assert not logged
    assert set(SIGNALS) == {signal_of(n).name for n in ports.outputs() + ports.inputs()}
    assert ports.inputs() == ["c1.speed", "c2.speed", "c3.speed", "c4.speed", "pusher.command"]
    # each variable of the type its signal declares (pythonfmu takes the type from the start value)
    kinds = {"Boolean": bool, "Integer": int, "Real": float}
    assert all(type(fmu.values[n]) is kinds[signal_of(n).type] for n in plant_outputs + fmu.input_names)
