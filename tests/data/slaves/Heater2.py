"""An FMI 2.0 co-simulation FMU exported by pythonfmu: the same heater as Heater3.py.

Used by the tests as an FMU the project did not write (a different exporter, typed variables).
pythonfmu has no Enumeration variables, so the mode is an Integer here.
"""

import math

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String


class Heater2(Fmi2Slave):
    author = "fmu-bridge tests"
    description = "First-order room temperature with a heater; typed variables"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.power = 0.0
        self.enabled = True
        self.mode = 2
        self.room = 20.0
        self.steps = 0
        self.heating = False
        self.gain = 0.01
        self.loss = 0.1
        self.ambient = 10.0
        self.label = "living room"
        discrete = Fmi2Variability.discrete
        self.register_variable(Real("power", causality=Fmi2Causality.input))
        self.register_variable(Boolean("enabled", causality=Fmi2Causality.input, variability=discrete))
        self.register_variable(Integer("mode", causality=Fmi2Causality.input, variability=discrete))
        self.register_variable(Real("room", causality=Fmi2Causality.output))
        self.register_variable(Integer("steps", causality=Fmi2Causality.output, variability=discrete))
        self.register_variable(Boolean("heating", causality=Fmi2Causality.output, variability=discrete))
        self.register_variable(
            Real("gain", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable)
        )
        self.register_variable(
            Real("loss", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        )
        self.register_variable(
            Real("ambient", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        )
        self.register_variable(
            String("label", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        )

    def do_step(self, current_time, step_size):
        factor = {1: 0.0, 2: 0.5, 3: 1.0}[int(self.mode)]
        heat = self.power * factor if self.enabled else 0.0
        self.heating = heat > 0.0
        target = self.ambient + self.gain * heat / self.loss
        self.room = target + (self.room - target) * math.exp(-self.loss * step_size)
        self.steps += 1
        return True
