"""The Van der Pol oscillator, x'' = mu (1 - x^2) x' - x, integrated with classical Runge-Kutta in 10 substeps
per communication step."""

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class Oscillator(Fmi2Slave):
    author = "fishfmu tests"
    description = "Van der Pol oscillator"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.x, self.v, self.mu = 2.0, 0.0, 1.0
        self.register_variable(Real("x", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("v", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("mu", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))

    def _f(self, x, v):
        return v, self.mu * (1.0 - x * x) * v - x

    def do_step(self, current_time, step_size):
        h = step_size / 10
        x, v = self.x, self.v
        for _ in range(10):
            k1 = self._f(x, v)
            k2 = self._f(x + h / 2 * k1[0], v + h / 2 * k1[1])
            k3 = self._f(x + h / 2 * k2[0], v + h / 2 * k2[1])
            k4 = self._f(x + h * k3[0], v + h * k3[1])
            x += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        self.x, self.v = x, v
        return True
