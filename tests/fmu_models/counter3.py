"""FMI 3.0: an Int32 counter, one up every ``period_s`` (like the Reference FMU Stair), and a UInt64 twice it."""

from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64, Int32, UInt64


class Counter3(Fmi3Slave):
    author = "fishfmu tests"
    description = "An Int32 counter, one up every period_s"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time = 0.0
        self.counter = 0
        self.double = 0
        self.period_s = 1.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Int32("counter", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete))
        self.register_variable(UInt64("double", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete))
        self.register_variable(Float64("period_s", causality=Fmi3Causality.parameter,
                                       variability=Fmi3Variability.tunable))

    def do_step(self, current_time, step_size):
        self.counter = int((current_time + step_size) / self.period_s + 1e-9)
        self.double = 2 * self.counter
        return True
