"""An FMI 3.0 co-simulation FMU exported by pythonfmu3 with array variables (row-major, FMI 3.0).

u (3) and k (3) are inputs; after a step from t to t + h: y[1,:] = u, y[2,:] = 10 u + (t + h),
n = k + 1.
"""

import numpy as np
from pythonfmu3 import Dimension, Float64, Fmi3Causality, Fmi3Slave, Fmi3Variability, Int64


class Arrays3(Fmi3Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.author = "fmu-bridge tests"
        self.description = "FMI 3.0 arrays: u[3], k[3] in; y[2,3], n[3] out"
        self.time = 0.0
        self.u = np.zeros(3)
        self.k = np.zeros(3, dtype=np.int64)
        self.y = np.zeros((2, 3))
        self.n = np.ones(3, dtype=np.int64)
        inp, out = Fmi3Causality.input, Fmi3Causality.output
        continuous, discrete = Fmi3Variability.continuous, Fmi3Variability.discrete
        three = [Dimension(start="3")]
        self.register_variable(Float64("time", causality=Fmi3Causality.independent, variability=continuous))
        # Own setters: pythonfmu3's default array setter calls np.reshape(newshape=...), gone in numpy 2.1.
        self.register_variable(
            Float64("u", causality=inp, variability=continuous, dimensions=three, setter=self._set_u)
        )
        self.register_variable(
            Int64("k", causality=inp, variability=discrete, dimensions=three, setter=self._set_k)
        )
        two_by_three = [Dimension(start="2"), Dimension(start="3")]
        self.register_variable(Float64("y", causality=out, variability=continuous, dimensions=two_by_three))
        self.register_variable(Int64("n", causality=out, variability=discrete, dimensions=three))

    def _set_u(self, values):
        self.u = np.asarray(values, dtype=np.float64).reshape(3)

    def _set_k(self, values):
        self.k = np.asarray(values, dtype=np.int64).reshape(3)

    def do_step(self, current_time, step_size):
        self.y = np.vstack([self.u, 10.0 * self.u + (current_time + step_size)])
        self.n = self.k + 1
        return True
