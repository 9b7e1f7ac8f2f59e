"""The plant of a fishfmu scenario as an FMU (made by `fishfmu export-fmu`; needs fishfmu in the host's Python).

This file is the FMU's slave script: ``export-fmu`` copies it into the FMU as ``fishfmu_plant.py``, where pythonfmu
finds the class. No entry point lets an exception out (see :mod:`fishfmu.cosim.plant_fmu`): pythonfmu would make it
fmi2Fatal and free the slave, and the host's next call would crash its process.
"""
from pathlib import Path

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

from fishfmu.cosim.plant_fmu import (PARAMETER_BOUNDS, SCENARIO_RESOURCE, SPEED_BOUNDS_MPS, PlantInFmu, never_raises,
                                     with_bounds)

NOT_A_VALUE = {Real: float("nan"), Integer: 0, Boolean: False, String: ""}
"""What a get of a value reference that is not of the type asked returns (with an error logged)."""
CAST = {Real: float, Integer: int, Boolean: bool, String: str}


class FishfmuPlant(Fmi2Slave):
    author = "fishfmu"
    description = "A salmon singulation line (fishfmu's Exudyn plant) with its fish"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.plant = PlantInFmu(Path(self.resources) / SCENARIO_RESOURCE, report=self.log_error)
        p = self.plant
        for name, bounds in PARAMETER_BOUNDS.items():
            self.register_variable(with_bounds(Integer(
                name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                getter=p.getter(name), setter=p.parameter_setter(name)), bounds))
        for name in p.input_names:
            if name in p.command_names:  # a device's command: any Boolean is valid
                self.register_variable(Boolean(name, causality=Fmi2Causality.input, variability=Fmi2Variability.discrete,
                                               start=False, getter=p.getter(name), setter=p.command_setter(name)))
                continue
            self.register_variable(with_bounds(Real(
                name, causality=Fmi2Causality.input, start=0.0, description=p.units[name],
                getter=p.getter(name), setter=p.speed_setter(name)), SPEED_BOUNDS_MPS))
        # outputs start as the line at rest (initial = exact): no photo-eye blocked, no load, no fish yet
        for name in p.output_names:
            start = p.values[name]
            if isinstance(start, bool) or isinstance(start, int):
                kind = Boolean if isinstance(start, bool) else Integer
                var = kind(name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                           initial=Fmi2Initial.exact, start=start, getter=p.getter(name))
            else:
                var = Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact, start=start,
                           description=p.units.get(name, ""), getter=p.getter(name))
            self.register_variable(var)

    def log_error(self, message):
        self.log(message, Fmi2Status.error)

    @never_raises(lambda: None)
    def exit_initialization_mode(self):
        self.plant.start()

    @never_raises(lambda current_time, step_size: False)
    def do_step(self, current_time, step_size):
        return self.plant.do_step(step_size)

    # canGetAndSetFMUstate = false: the plant's state (Exudyn's) is not saved; a host that restores one anyway is
    # told so, and the steps after it are refused (the plant would go on from where it is, not from the state)
    @never_raises(lambda: None)
    def _get_fmu_state(self):
        self.log_error("fmi2GetFMUstate: this FMU does not save its state (canGetAndSetFMUstate = false)")

    @never_raises(lambda state: None)
    def _set_fmu_state(self, state):
        self.plant.refuse("fmi2SetFMUstate", "fmi2SetFMUstate refused: this FMU cannot restore a state "
                                             "(canGetAndSetFMUstate = false); fmi2Reset to start again")

    @staticmethod
    def _fmu_state_from_bytes(state):
        return None  # nothing is saved (above), and bytes that are not JSON must not raise

    # pythonfmu's own get and set functions raise (so crash the host) on a value reference of another type, an
    # unknown one or a variable without a setter (an output)
    @never_raises(lambda vrs: [NOT_A_VALUE[Real]] * len(vrs))
    def get_real(self, vrs):
        return self._get(Real, vrs)

    @never_raises(lambda vrs: [NOT_A_VALUE[Integer]] * len(vrs))
    def get_integer(self, vrs):
        return self._get(Integer, vrs)

    @never_raises(lambda vrs: [NOT_A_VALUE[Boolean]] * len(vrs))
    def get_boolean(self, vrs):
        return self._get(Boolean, vrs)

    @never_raises(lambda vrs: [NOT_A_VALUE[String]] * len(vrs))
    def get_string(self, vrs):
        return self._get(String, vrs)

    @never_raises(lambda vrs, values: None)
    def set_real(self, vrs, values):
        self._set(Real, vrs, values)

    @never_raises(lambda vrs, values: None)
    def set_integer(self, vrs, values):
        self._set(Integer, vrs, values)

    @never_raises(lambda vrs, values: None)
    def set_boolean(self, vrs, values):
        self._set(Boolean, vrs, values)

    @never_raises(lambda vrs, values: None)
    def set_string(self, vrs, values):
        self._set(String, vrs, values)

    def _get(self, kind, vrs):
        values = []
        for vr in vrs:
            var = self.vars.get(vr)
            if isinstance(var, kind):
                values.append(CAST[kind](var.getter()))
            else:
                self.log_error(f"get{kind.__name__}: value reference {vr} is not a {kind.__name__} variable of "
                               f"this FMU ({var.name if var else 'no variable'}); {NOT_A_VALUE[kind]!r} returned")
                values.append(NOT_A_VALUE[kind])
        return values

    def _set(self, kind, vrs, values):
        for vr, value in zip(vrs, values):
            var = self.vars.get(vr)
            if isinstance(var, kind) and var.setter is not None:
                var.setter(value)
            else:
                name = var.name if var else f"value reference {vr}"
                what = "an output" if var is not None and var.setter is None else f"not a {kind.__name__} variable"
                self.plant.refuse(name, f"set{kind.__name__} of {name} refused: it is {what} of this FMU")
