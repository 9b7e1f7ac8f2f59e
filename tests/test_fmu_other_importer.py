"""Our FMUs in a second FMI importer, libcosim (Open Simulation Platform, via libcosimpy), give the
same outputs as through fmpy for the same parameters and inputs: the FMUs do not lean on fmpy's
particular calling order.  Both run the same binary, so they must agree to rounding (1e-9)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.fmu_helpers import start_slave

libcosimpy = pytest.importorskip("libcosimpy")
from libcosimpy.CosimEnums import CosimVariableType  # noqa: E402
from libcosimpy.CosimExecution import CosimExecution  # noqa: E402
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level  # noqa: E402
from libcosimpy.CosimManipulator import CosimManipulator  # noqa: E402
from libcosimpy.CosimObserver import CosimObserver  # noqa: E402
from libcosimpy.CosimSlave import CosimLocalSlave  # noqa: E402

DT_S = 0.01
Script = list[tuple[int, dict[str, float | int | bool]]]  # (step index, inputs to set before that step)


def run_fmpy(unzip_dir: Path, parameters: dict, script: Script, n_steps: int, outputs: list[str]) -> np.ndarray:
    slave = start_slave(unzip_dir, parameters)
    rows = []
    for k in range(n_steps):
        for step, values in script:
            if step == k:
                slave.set(**values)
        slave.step(DT_S)
        rows.append([float(v) for v in slave.get(*outputs).values()])
    slave.close()
    return np.array(rows)


def run_libcosim(fmu: Path, parameters: dict, script: Script, n_steps: int, outputs: list[str]) -> np.ndarray:
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(round(DT_S * 1e9))  # libcosim counts nanoseconds
    index = execution.add_local_slave(CosimLocalSlave(str(fmu), "uut"))
    variables = {v.name.decode(): v for v in execution.slave_variables(index)}
    kind = {CosimVariableType.REAL.value: "real", CosimVariableType.INTEGER.value: "integer",
            CosimVariableType.BOOLEAN.value: "boolean"}
    manipulator, observer = CosimManipulator.create_override(), CosimObserver.create_last_value()
    execution.add_manipulator(manipulator)
    execution.add_observer(observer)
    for name, value in parameters.items():
        setter = getattr(execution, f"{kind[variables[name].type]}_initial_value")
        assert setter(index, variables[name].reference, value), name
    rows = []
    for k in range(n_steps):
        for step, values in script:
            if step != k:
                continue
            for name, value in values.items():
                override = getattr(manipulator, f"slave_{kind[variables[name].type]}_values")
                assert override(index, [variables[name].reference], [value]), name
        assert execution.step(), f"libcosim step {k} failed: {execution.status()}"
        row = []
        for name in outputs:
            read = getattr(observer, f"last_{kind[variables[name].type]}_values")
            row.append(float(read(index, [variables[name].reference])[0]))
        rows.append(row)
    execution.stop()
    return np.array(rows)


def test_drive_gives_the_same_outputs_in_libcosim(builtin_fmus: dict[str, Path],
                                                  unzipped_fmus: dict[str, Path]) -> None:
    parameters = {"slip_compensation": 0.5, "ramp_acceleration": 3.0}
    script: Script = [(0, {"speed_setpoint": 1.4}), (100, {"load_force": 120.0}), (150, {"speed_setpoint": 0.6})]
    outputs = ["belt_speed", "motor_torque", "electrical_power", "ramp_reference"]
    ours = run_fmpy(unzipped_fmus["conveyor_drive"], parameters, script, 250, outputs)
    theirs = run_libcosim(builtin_fmus["conveyor_drive"], parameters, script, 250, outputs)
    assert ours[:, 0].max() > 1.3  # the run did something: the belt ran up
    assert theirs == pytest.approx(ours, rel=1e-9, abs=1e-9)


def test_controller_gives_the_same_outputs_in_libcosim(builtin_fmus: dict[str, Path],
                                                       unzipped_fmus: dict[str, Path]) -> None:
    parameters = {"n_belts": 3, "startup_delay": 0.5, "mode": 1, "jam_time": 1.0, "jam_stop": True}
    speeds = {"belt_speed_1": 0.3, "belt_speed_2": 0.55, "belt_speed_3": 0.85}
    script: Script = [(0, speeds), (120, {"pe_1": True}), (150, {"pe_1": False}), (160, {"pe_1": True}),
                      (190, {"pe_1": False}), (200, {"pe_2": True}), (350, {"pe_2": False})]
    outputs = ["setpoint_1", "setpoint_2", "setpoint_3", "gap_events", "jam", "jam_belt", "last_gap_m_1"]
    ours = run_fmpy(unzipped_fmus["singulation_controller"], parameters, script, 400, outputs)
    theirs = run_libcosim(builtin_fmus["singulation_controller"], parameters, script, 400, outputs)
    assert ours[:, outputs.index("gap_events")].max() == 1 and ours[:, outputs.index("jam")].max() == 1
    assert theirs == pytest.approx(ours, rel=1e-9, abs=1e-9)
