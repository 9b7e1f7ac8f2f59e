"""Every FMI 2.0 type in and out unchanged: what comes in at a step goes out at its end."""

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String


class Passthrough(Fmi2Slave):
    author = "fishfmu tests"
    description = "Real, Integer, Boolean and String inputs copied to outputs"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.real_in = self.real_out = 0.0
        self.int_in = self.int_out = 0
        self.bool_in = self.bool_out = False
        self.str_in = self.str_out = ""
        for name, kind in (("real", Real), ("int", Integer), ("bool", Boolean), ("str", String)):
            discrete = {} if kind is Real else {"variability": Fmi2Variability.discrete}
            self.register_variable(kind(f"{name}_in", causality=Fmi2Causality.input, **discrete))
            self.register_variable(kind(f"{name}_out", causality=Fmi2Causality.output, **discrete))

    def do_step(self, current_time, step_size):
        self.real_out, self.int_out = self.real_in, self.int_in
        self.bool_out, self.str_out = self.bool_in, self.str_in
        return True
