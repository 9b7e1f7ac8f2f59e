"""A first-order lag, dx/dt = (u - x) / tau, solved exactly over each step (u held): x is a state with a start
value of its own (initial = exact)."""

import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class FirstOrder(Fmi2Slave):
    author = "fishfmu tests"
    description = "First-order lag of its input"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.x = 0.5
        self.tau = 0.4
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("x", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))

    def do_step(self, current_time, step_size):
        self.x = self.u + (self.x - self.u) * math.exp(-step_size / self.tau)
        return True
