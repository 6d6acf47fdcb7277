"""An FMI 2.0 co-simulation FMU exported by pythonfmu, shaped like a Modelica tool's export.

No inputs, no outputs and no tunable parameters: the states are locals with Modelica names
(``body.frame_a.r_0[1]``, ``der(body.frame_a.r_0[1])``), and a fixed parameter has a quoted name.
After a step from t to t + h: r_0[1] = cos(w (t + h)), r_0[2] = sin(w (t + h)).
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Names2(Fmi2Slave):
    author = "fmu-bridge tests"
    description = "A point on a circle; locals only, Modelica-style names"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = {"'angular speed'": 1.0, "body.frame_a.r_0[1]": 1.0, "body.frame_a.r_0[2]": 0.0}
        self.values["der(body.frame_a.r_0[1])"] = 0.0
        self.values["der(body.frame_a.r_0[2])"] = 1.0
        fixed, local = Fmi2Variability.fixed, Fmi2Causality.local
        self._add("'angular speed'", Fmi2Causality.parameter, fixed)
        for name in ("body.frame_a.r_0[1]", "body.frame_a.r_0[2]"):
            self._add(name, local, Fmi2Variability.continuous)
            self._add(f"der({name})", local, Fmi2Variability.continuous)

    def _add(self, name, causality, variability):
        def getter():
            return self.values[name]

        def setter(value):
            self.values[name] = value

        self.register_variable(
            Real(name, causality=causality, variability=variability, getter=getter, setter=setter),
            nested=False,
        )

    def do_step(self, current_time, step_size):
        w, t = self.values["'angular speed'"], current_time + step_size
        self.values["body.frame_a.r_0[1]"] = math.cos(w * t)
        self.values["body.frame_a.r_0[2]"] = math.sin(w * t)
        self.values["der(body.frame_a.r_0[1])"] = -w * math.sin(w * t)
        self.values["der(body.frame_a.r_0[2])"] = w * math.cos(w * t)
        return True
