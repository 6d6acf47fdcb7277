"""The FMI 3.0 twin of Unimportable2.py, exported by pythonfmu3."""

import fmu_bridge_absent_package  # noqa: F401
from pythonfmu3 import Float64, Fmi3Causality, Fmi3Slave


class Unimportable3(Fmi3Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Float64("u", causality=Fmi3Causality.input))
        self.register_variable(Float64("y", causality=Fmi3Causality.output))

    def do_step(self, current_time, step_size):
        self.y = self.u
        return True
