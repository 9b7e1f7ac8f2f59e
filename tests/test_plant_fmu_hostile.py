"""The plant FMU (``fishfmu export-fmu``) driven by a hostile or careless master (issue 28): bad input is refused
with a logged message naming the variable, and the host's process survives to call fmi2Terminate and
fmi2FreeInstance.

pythonfmu (0.7) turns any exception in the slave into fmi2Fatal and frees it, so the host's next call crashes its
process (exit 139). The host here is a separate process (this file run as a script: :func:`host`) that drives
each case through fmpy on a fresh instance and prints one JSON line per FMI call, so a crash fails these tests
instead of killing pytest. The refusal status is fmi2Discard: pythonfmu's doStep has no other non-fatal failure
(see :mod:`fishfmu.cosim.plant_fmu`).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
FMI_OK, FMI_DISCARD, FMI_ERROR = 0, 2, 3

INIT = [("setupExperiment",), ("enterInitializationMode",), ("exitInitializationMode",)]
STEP = ("doStep", 0.0, 0.01)

# case -> (FMI calls, what the refused call's message names); the last call is the one refused
HOSTILE = {
    "nan_belt_speed": (INIT + [("setReal", "c1.speed", math.nan), ("getReal", "c1.speed"), STEP], "c1.speed = nan"),
    "inf_belt_speed": (INIT + [("setReal", "c2.speed", math.inf), STEP], "c2.speed = inf"),
    "belt_speed_past_its_max": (INIT + [("setReal", "c3.speed", -25.0), STEP], "c3.speed = -25 m/s"),
    "nan_step": (INIT + [("doStep", 0.0, math.nan)], "h = nan s"),
    "inf_step": (INIT + [("doStep", 0.0, math.inf)], "h = inf s"),
    "negative_step": (INIT + [("doStep", 0.0, -0.01)], "positive"),
    "step_not_a_whole_number_of_communication_steps": (INIT + [("doStep", 0.0, 0.015)], "whole multiple"),
    "step_before_initialisation": ([STEP], "not initialised"),
    "seed_minus_5": (INIT[:2] + [("setInteger", "seed", -5), INIT[2], STEP], "seed = -5"),
    "fish_count_0": (INIT[:2] + [("setInteger", "fish_count", 0), INIT[2], STEP], "fish_count = 0"),
    "fish_count_5000": (INIT[:2] + [("setInteger", "fish_count", 5000), INIT[2], STEP], "fish_count = 5000"),
    "fixed_parameter_set_after_initialisation": (INIT + [("setInteger", "seed", 7), STEP], "seed = 7"),
    "an_output_set": (INIT + [("setReal", "c1.load_force", 1.0), STEP], "c1.load_force"),
    "step_right_after_reset": (INIT + [STEP, ("reset",), ("doStep", 0.01, 0.01)], "not initialised"),
    # canGetAndSetFMUstate = false, but a state restored anyway (from bytes that are not a state)
    "state_restored": (INIT + [STEP, ("getFMUstate",), ("serializeFMUstate",), ("deSerializeFMUstate", "garbage"),
                               ("setFMUstate",), ("doStep", 0.01, 0.01)], "fmi2SetFMUstate"),
}
# cases that must run through (every call fmi2OK, the host alive), named for what they show
GOOD = {
    # a refused speed keeps the belt's speed and blocks the steps until a valid one is set
    "valid_speed_after_a_refused_one": INIT + [("setReal", "c1.speed", math.nan), STEP, ("setReal", "c1.speed", 0.5),
                                               ("doStep", 0.0, 0.01), ("getReal", "c1.speed")],
    # the same plant (seed 3, 4 fish, the belts running) before and after fmi2Reset: a fresh plant each time
    "reset_and_initialised_again": 2 * ([("reset",)] + INIT[:2] + [
        ("setInteger", "seed", 3), ("setInteger", "fish_count", 4), ("setReal", "c1.speed", 0.3)]
        + INIT[2:] + [("doStep", 0.0, 5.5), ("getInteger", "fish_dropped"), ("getReal", "c1.load_mass")]),
    # a get of a value reference of another type: the value (NaN) and an error message, not a crash
    "get_real_of_an_integer": INIT + [("getReal", "fish_count")],
}


def host(fmu: str, cases: list[str]) -> None:
    """Run ``cases`` (of :data:`HOSTILE` and :data:`GOOD`), each on a fresh instance, and print one JSON line per
    FMI call: the case, the function, its status, its result and the messages the FMU logged during it. Each case
    ends with a get of every kind, fmi2Terminate and fmi2FreeInstance, then a line ``{"survived": case}``."""
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import (FMU2Slave, calloc, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, free)
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(fmu)
    logged: list[tuple[int, str]] = []

    def log(component, instance, status, category, message):  # noqa: ANN001, ANN202 - an FMI callback
        logged.append((status, message.decode("utf-8")))
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(log)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    for case in cases:
        calls = HOSTILE[case][0] if case in HOSTILE else GOOD[case]
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=case)
        slave.instantiate(callbacks=callbacks, loggingOn=True)
        epilogue = [("getReal", "c1.load_force"), ("getInteger", "fish_dropped"), ("getBoolean", "pe_c1.blocked"),
                    ("terminate",), ("freeInstance",)]
        state = None
        for name, *args in calls + epilogue:
            if name in ("serializeFMUstate", "setFMUstate"):
                args = [state]
            elif name == "deSerializeFMUstate":
                args = [args[0].encode()]
            elif name.startswith(("set", "get")) and name not in ("setupExperiment", "getFMUstate"):
                args = [[vr[args[0]]], *([[a] for a in args[1:]])]
            logged.clear()
            try:
                result, status = getattr(slave, name)(*args), FMI_OK
            except FMICallException as exc:
                result, status = None, exc.status
            if name in ("getFMUstate", "deSerializeFMUstate"):
                state = result
            print(json.dumps({"case": case, "call": name, "status": status, "result": result, "log": logged},
                             default=repr), flush=True)
        print(json.dumps({"survived": case}), flush=True)


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "plant.fmu"
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "export-fmu", str(PAPER), "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert cli.returncode == 0, cli.stderr
    return out


@pytest.fixture(scope="module")
def hosted(plant_fmu) -> dict[str, list[dict]]:
    """Every case run by one host process (one Python and Exudyn start-up for all): case -> its calls, each with
    ``survived`` (True on the case's last record if the host lived through it); a crash leaves the case it
    happened in, and those after it, without."""
    cases = [*HOSTILE, *GOOD]
    proc = subprocess.run([sys.executable, __file__, str(plant_fmu), *cases], capture_output=True, text=True,
                          timeout=600, cwd=ROOT)
    records: dict[str, list[dict]] = {case: [] for case in cases}
    for line in proc.stdout.splitlines():
        if line.startswith("{"):
            rec = json.loads(line)
            if "survived" in rec:
                records[rec["survived"]][-1]["survived"] = True
            else:
                records[rec["case"]].append(rec)
    for calls in records.values():
        calls.append({"returncode": proc.returncode, "stderr": proc.stderr[-2000:]})
    return records


def _survived(calls: list[dict]) -> list[dict]:
    """The case's FMI calls, asserting the host lived through the case and its terminate and freeInstance."""
    end = calls.pop()
    assert calls and calls[-1].get("survived"), (
        f"the host crashed (exit {end['returncode']}) in this case or one before it, after "
        f"{[(c['call'], c['status']) for c in calls]}: {end['stderr']}")
    assert [(c["call"], c["status"]) for c in calls[-5:]] == [
        ("getReal", FMI_OK), ("getInteger", FMI_OK), ("getBoolean", FMI_OK), ("terminate", FMI_OK),
        ("freeInstance", FMI_OK)]
    return calls[:-5]


def _errors(call: dict) -> list[str]:
    return [message for status, message in call["log"] if status == FMI_ERROR]


@pytest.mark.parametrize("case", list(HOSTILE))
def test_bad_input_is_refused_with_a_message_and_the_host_survives(hosted, case):
    calls = _survived(list(hosted[case]))
    names = HOSTILE[case][1]
    refused = calls[-1]
    assert refused["call"] == "doStep" and refused["status"] == FMI_DISCARD, refused
    messages = _errors(refused)
    assert len(messages) == 1 and names in messages[0] and "\n" not in messages[0], messages
    for call in calls[:-1]:  # every other call went through; a refused set says so when it is made
        assert call["status"] == FMI_OK, call
        if call["call"].startswith("set") and call["call"] != "setupExperiment":
            assert len(_errors(call)) == 1 and names in _errors(call)[0], call
    if case == "nan_belt_speed":  # the belt keeps the speed it had
        assert calls[-2]["call"] == "getReal" and calls[-2]["result"] == [0.0]


def test_a_valid_speed_after_a_refused_one_lets_the_plant_step_on(hosted):
    calls = _survived(list(hosted["valid_speed_after_a_refused_one"]))
    assert [(c["call"], c["status"]) for c in calls[3:]] == [
        ("setReal", FMI_OK), ("doStep", FMI_DISCARD), ("setReal", FMI_OK), ("doStep", FMI_OK), ("getReal", FMI_OK)]
    assert calls[-2]["log"] == [] and calls[-1]["result"] == [0.5]


def test_after_reset_and_a_new_initialisation_the_plant_starts_afresh(hosted):
    calls = _survived(list(hosted["reset_and_initialised_again"]))
    assert all(c["status"] == FMI_OK and c["log"] == [] for c in calls), calls
    gets = [c["result"] for c in calls if c["call"].startswith("get")]
    first, second = gets[:2], gets[2:]
    # the scenario drops from 4 s every 0.25 s: 4 fish by 5.5 s, on c1 (salmon of 0.42-0.75 m: over 0.5 kg each)
    assert first[0] == [4] and first[1][0] > 4 * 0.5
    assert second == first  # the same fish, the same forces to the last bit: nothing left from the first run


def test_a_get_of_another_type_returns_nan_with_a_message(hosted):
    calls = _survived(list(hosted["get_real_of_an_integer"]))
    get = calls[-1]
    assert get["status"] == FMI_OK and math.isnan(get["result"][0])
    assert len(_errors(get)) == 1 and "fish_count" in _errors(get)[0] and "not a Real" in _errors(get)[0]


def test_the_parameters_and_inputs_declare_their_bounds(plant_fmu):
    from fmpy import read_model_description
    md = {v.name: v for v in read_model_description(str(plant_fmu)).modelVariables}
    bounds = {name: (float(v.min), float(v.max)) for name, v in md.items() if v.min is not None}
    assert bounds == {"seed": (0, 2**31 - 1), "fish_count": (1, 2000),
                      **{f"c{i}.speed": (-10.0, 10.0) for i in range(1, 5)}}


def test_a_plant_that_stops_refuses_the_steps_after_it_and_keeps_its_outputs():
    from plant.errors import SimulationError

    from fishfmu.cosim.plant_fmu import PlantInFmu
    logged: list[str] = []
    pim = PlantInFmu(PAPER, report=logged.append)
    pim.parameter_setter("fish_count")(2)
    pim.start()
    assert pim.do_step(0.02) and logged == []
    before = dict(pim.values)

    def blow_up(speeds, commands=None):  # noqa: ANN001, ANN202
        raise SimulationError("numerical blow-up: fish 'f1' moves at 31.0 m/s", 0.03)
    pim.plant.step = blow_up
    assert not pim.do_step(0.01)
    assert not pim.do_step(0.01)
    assert logged == ["doStep(h = 0.01 s) not done: the plant stopped: at t = 0.030 s: numerical blow-up: fish 'f1' "
                      "moves at 31.0 m/s"] + [
        "doStep(h = 0.01 s) not done: the plant stopped: at t = 0.030 s: numerical blow-up: fish 'f1' moves at "
        "31.0 m/s (fmi2Reset and initialise again to start over)"]
    assert pim.values == before


def test_an_unexpected_exception_in_an_entry_point_is_logged_not_raised():
    from fishfmu.cosim.plant_fmu import never_raises

    class Slave:
        logged: list[str] = []

        def log_error(self, message: str) -> None:
            self.logged.append(message)

        @never_raises(lambda current_time, step_size: False)
        def do_step(self, current_time: float, step_size: float) -> bool:
            return {}["no such key"]
    slave = Slave()
    assert slave.do_step(0.0, 0.01) is False
    assert slave.logged == ["internal error in do_step (a bug in fishfmu; please report it): KeyError('no such key')"]


if __name__ == "__main__":
    host(sys.argv[1], sys.argv[2:])
