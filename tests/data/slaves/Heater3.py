"""An FMI 3.0 co-simulation FMU exported by pythonfmu3: a room heater with a mode switch.

Used by the tests as an FMU the project did not write (a different exporter, typed variables).
"""

import math
from enum import Enum

from pythonfmu3 import (
    Boolean,
    Enumeration,
    EnumerationType,
    Float64,
    Fmi3Causality,
    Fmi3Slave,
    Fmi3Variability,
    Int32,
    String,
)


class Mode(Enum):
    off = 1
    eco = 2
    boost = 3


class ScalarEnumeration(Enumeration):
    """pythonfmu3 0.3 leaves the array helpers off Enumeration; scalar ones are all we need."""

    dimensions: list = []

    def size(self, variables):
        return 1


class Heater3(Fmi3Slave):
    author = "fmu-bridge tests"
    description = "First-order room temperature with a heater; typed variables of every kind"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time = 0.0
        self.power = 0.0  # input, W
        self.enabled = True  # input
        self.mode = 2  # input enumeration
        self.room = 20.0  # output, degC
        self.steps = 0  # output Int32
        self.heating = False  # output Boolean
        self.gain = 0.01  # tunable parameter, K/(W s)
        self.loss = 0.1  # fixed parameter, 1/s
        self.ambient = 10.0  # fixed parameter, degC
        self.label = "living room"
        self.register_variable(
            Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous)
        )
        self.register_variable(Float64("power", causality=Fmi3Causality.input, start=0.0))
        self.register_variable(
            Boolean(
                "enabled", causality=Fmi3Causality.input, start=True, variability=Fmi3Variability.discrete
            )
        )
        mode = ScalarEnumeration(
            "mode",
            causality=Fmi3Causality.input,
            start=2,
            variability=Fmi3Variability.discrete,
            declared_type="Mode",
        )
        self.register_variable(mode, var_type=EnumerationType("Mode", values=Mode))
        self.register_variable(Float64("room", causality=Fmi3Causality.output))
        self.register_variable(
            Int32("steps", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete)
        )
        self.register_variable(
            Boolean("heating", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete)
        )
        self.register_variable(
            Float64(
                "gain", causality=Fmi3Causality.parameter, variability=Fmi3Variability.tunable, start=0.01
            )
        )
        self.register_variable(
            Float64("loss", causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed, start=0.1)
        )
        self.register_variable(
            Float64(
                "ambient", causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed, start=10.0
            )
        )
        self.register_variable(
            String(
                "label",
                causality=Fmi3Causality.parameter,
                variability=Fmi3Variability.fixed,
                start="living room",
            )
        )

    def do_step(self, current_time, step_size):
        factor = {1: 0.0, 2: 0.5, 3: 1.0}[int(self.mode)]
        heat = self.power * factor if self.enabled else 0.0
        self.heating = heat > 0.0
        # exact solution of dT/dt = -loss (T - ambient) + gain * heat over one step
        target = self.ambient + self.gain * heat / self.loss
        self.room = target + (self.room - target) * math.exp(-self.loss * step_size)
        self.steps += 1
        return True
