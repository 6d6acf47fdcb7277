"""A pythonfmu export that runs correctly and then aborts the process it ran in, at its exit.

It stands for the Python-backed FMUs whose embedded interpreter's teardown aborts, crashes or
hangs after a correct run: whatever process loaded it ends with SIGABRT.
"""

import atexit
import os

from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class AbortAtExit2(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        self.armed = False

    def do_step(self, current_time, step_size):
        if not self.armed:  # not at export: pythonfmu's build creates an instance too
            atexit.register(os.abort)
            self.armed = True
        self.y += self.u * step_size
        return True
