"""A pythonfmu export whose module imports a package that is only there when it is built.

The tests build it with a stand-in ``fmu_bridge_absent_package`` on the path and run it without,
so the FMU's class import fails inside ``fmi2Instantiate`` as it does for a user who lacks one of
an FMU's Python packages.
"""

import fmu_bridge_absent_package  # noqa: F401
from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class Unimportable2(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        self.y = self.u
        return True
