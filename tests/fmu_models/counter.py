"""An Integer counter, one up every ``period_s`` (like the Modelica Reference FMU Stair)."""

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


class Counter(Fmi2Slave):
    author = "fishfmu tests"
    description = "An Integer counter, one up every period_s"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.counter = 0
        self.period_s = 1.0
        self.register_variable(Integer("counter", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete))
        self.register_variable(Real("period_s", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))

    def do_step(self, current_time, step_size):
        self.counter = int((current_time + step_size) / self.period_s + 1e-9)
        return True
