"""Connections checked against FMU variables and plant ports; stepping order; constants and events."""

from __future__ import annotations

import zlib
from pathlib import Path

import pytest

from plant.errors import InputError

from fishfmu.fmu.archive import FmuVariable
from fishfmu.scenario.schema import load_scenario
from fishfmu.scenario.wiring import resolve_wiring

PAPER = Path(__file__).parents[1] / "scenarios" / "paper_dump.toml"


def var(name: str, causality: str, type_: str = "Real") -> FmuVariable:
    # a distinct value reference per name: one reference would make them aliases of one variable
    return FmuVariable(name, causality, type_, "continuous", zlib.crc32(name.encode()), None, None)


def drive_vars() -> dict[str, FmuVariable]:
    return {v.name: v for v in [var("speed_setpoint", "input"), var("load_force", "input"),
                                var("belt_speed", "output"), var("gear_ratio", "parameter")]}


def controller_vars() -> dict[str, FmuVariable]:
    vs = [var(f"pe_{i}", "input", "Boolean") for i in range(1, 5)]
    vs += [var(f"belt_speed_{i}", "input") for i in range(1, 5)]
    vs += [var(f"setpoint_{i}", "output") for i in range(1, 5)]
    return {v.name: v for v in vs}


def fmu_vars() -> dict[str, dict[str, FmuVariable]]:
    return {"controller": controller_vars(), **{f"drive_c{i}": drive_vars() for i in range(1, 5)}}


def paper(**overrides):
    return load_scenario(PAPER, overrides)


def test_paper_wiring_orders_controller_before_drives_and_breaks_the_speed_feedback():
    w = resolve_wiring(paper(), fmu_vars())
    assert w.order == ["controller", "drive_c1", "drive_c2", "drive_c3", "drive_c4"]
    assert len(w.connections) == 20
    pe = [c for c in w.connections if c.source.key == "plant.pe_c1.blocked"][0]
    assert (pe.source.type, pe.target.key) == ("Boolean", "controller.pe_1")


@pytest.mark.parametrize("connection, message", [
    ("drive_c1.belt_sped -> plant.c1.speed", "did you mean 'drive_c1.belt_speed'"),
    ("drive_c9.belt_speed -> plant.c1.speed", "no FMU or plant named 'drive_c9'"),
    ("drive_c1.speed_setpoint -> plant.c1.speed", "is an input; a connection needs an output as source"),
    ("drive_c1.belt_speed -> drive_c2.belt_speed", "is an output; a connection needs an input as target"),
    ("drive_c1.belt_speed -> controller.pe_1", "'drive_c1.belt_speed' is Real but 'controller.pe_1' is Boolean: no conversion"),
    ("drive_c2.belt_speed -> plant.c1.speed", "connected twice"),
    ("plant.c1.load_force -> plant.c2.speed", "'plant.c1.load_force' is in N but 'plant.c2.speed' in m/s"),
    ("drive_c1.belt_speed -> plant.c1.sped", "did you mean 'plant.c1.speed'"),
    ("plant.c1.load_force -> plant.c1.load_mass", "is an output, it cannot be a target"),
])
def test_bad_connections_name_the_key_and_what_is_wrong(connection, message):
    sc = paper()
    sc.wiring.connections.append(connection)
    with pytest.raises(InputError) as info:
        resolve_wiring(sc, fmu_vars(), "paper_dump.toml")
    text = str(info.value)
    assert message in text and "wiring.connections[20]" in text


def test_unconnected_belt_needs_a_constant():
    sc = paper()
    sc.wiring.connections = [c for c in sc.wiring.connections if "-> plant.c3.speed" not in c]
    with pytest.raises(InputError, match="not connected and no constant given for: plant.c3.speed"):
        resolve_wiring(sc, fmu_vars())
    sc.wiring.inputs["plant.c3.speed"] = 0.7
    w = resolve_wiring(sc, fmu_vars())
    assert w.constants == {"plant.c3.speed": 0.7}


def test_event_on_an_unknown_variable_is_rejected():
    sc = paper(event=[{"t_s": 5.0, "target": "drive_c2.speed_setpont", "action": "override", "value": 0.0}])
    with pytest.raises(InputError, match="event\\[0\\].target.*did you mean 'drive_c2.speed_setpoint'"):
        resolve_wiring(sc, fmu_vars())


def test_algebraic_loop_of_direct_feedthrough_cannot_be_ordered():
    sc = paper()
    # pretend the drives' belt speed and the controller's setpoints were declared direct feedthrough
    feed = {"controller": {"setpoint_1"}, "drive_c1": {"belt_speed"}}
    with pytest.raises(InputError, match="algebraic loop: .*controller.*drive_c1"):
        resolve_wiring(sc, fmu_vars(), "paper_dump.toml", feed)
    # the same cycle of state outputs is fine: the controller (listed first) steps first
    assert resolve_wiring(sc, fmu_vars(), None, {}).order[0] == "controller"


def test_jacobi_keeps_the_listed_order():
    sc = paper()
    sc.run.coupling = "jacobi"
    sc.fmu = list(reversed(sc.fmu))
    w = resolve_wiring(sc, fmu_vars())
    assert w.order == ["drive_c4", "drive_c3", "drive_c2", "drive_c1", "controller"]


@pytest.mark.parametrize("event, where, message", [
    ({"target": "plant.pe_c1.blocked", "action": "bias", "value": 1.0}, "event[0].action",
     "'plant.pe_c1.blocked' is a Boolean; it can be overridden or reset, not biased"),
    ({"target": "controller.label", "action": "override", "value": 1.0}, "event[0].target",
     "'controller.label' is a String; events set numbers and booleans"),
])
def test_events_that_do_not_fit_the_type_of_their_target_are_rejected(event, where, message):
    fmus = fmu_vars()
    fmus["controller"]["label"] = var("label", "input", "String")
    sc = paper(event=[{"t_s": 1.0, **event}])
    with pytest.raises(InputError) as failure:
        resolve_wiring(sc, fmus, "paper_dump.toml")
    assert failure.value.where == where and message in str(failure.value)
    sc = paper(event=[{"t_s": 1.0, "target": "plant.pe_c1.blocked", "action": "override", "value": True},
                      {"t_s": 2.0, "target": "controller.label", "action": "reset"}])
    resolve_wiring(sc, fmus)  # overriding a Boolean and resetting a String are fine


def test_string_input_cannot_be_given_a_numeric_constant():
    fmus = fmu_vars()
    fmus["controller"]["label"] = var("label", "input", "String")
    sc = paper(**{"wiring.inputs": {"controller.label": 1.0}})
    with pytest.raises(InputError, match="wiring.inputs.controller.label.*is a String input"):
        resolve_wiring(sc, fmus, "paper_dump.toml")
