"""FMI 3.0: a first-order lag whose state, a shaft speed, is declared through a type with a unit (rpm), as the
Reference FMU BouncingBall declares its height; x approaches the input u with time constant tau."""

import math

from pythonfmu3 import Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Float64, Float64Type, Unit


class Shaft3(Fmi3Slave):
    author = "fishfmu tests"
    description = "First-order lag in rpm"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time = 0.0
        self.u = 0.0
        self.speed = 100.0
        self.tau = 0.5
        self.register_units([Unit("rpm", rad=1, s=-1, factor=2 * math.pi / 60)])
        rpm = Float64Type("AngularVelocity", unit="rpm")
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Float64("u", causality=Fmi3Causality.input), var_type=rpm)
        self.register_variable(Float64("speed", causality=Fmi3Causality.output, initial=Fmi3Initial.exact),
                               var_type=rpm)
        self.register_variable(Float64("tau", causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed))

    def do_step(self, current_time, step_size):
        self.speed = self.u + (self.speed - self.u) * math.exp(-step_size / self.tau)
        return True
