"""An FMI 2.0 co-simulation FMU exported by pythonfmu whose default experiment runs for 1e8 s at
0.01 s per step (1e10 steps): ``init`` must still write an experiment that ``check`` accepts.

A tank: level' = inflow - outflow_rate * level, with a tunable outflow rate.
"""

from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class LongRun2(Fmi2Slave):
    author = "fmu-bridge tests"
    description = "A tank level over a very long default experiment"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1e8, step_size=0.01)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.inflow = 0.0
        self.outflow_rate = 0.1
        self.level = 1.0
        self.register_variable(Real("inflow", causality=Fmi2Causality.input))
        self.register_variable(
            Real("outflow_rate", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable)
        )
        self.register_variable(Real("level", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        self.level += step_size * (self.inflow - self.outflow_rate * self.level)
        return True
