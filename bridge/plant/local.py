"""``LocalFmuPlant``: one FMU instance in this process (the fastest plant, and what nodes serve).

A step writes the inputs, advances ``n`` FMU steps (``sampling_time = n * h``) and reads the
outputs, in one native call where the FMU allows it (``bridge.fmu.sample``), else through typed
``SignalGroup`` calls; FMU errors become :class:`StepError` with the FMU's own log
(``bridge.plant.instance``, shared with a system's in-process components).
"""

from __future__ import annotations

from bridge.fmu import state_file
from bridge.fmu.exit_guard import guard_native_exit
from bridge.fmu.opening import open_model
from bridge.fmu.state_file import StateFile
from bridge.plant.instance import FmuInstancePlant
from bridge.plant.spec import PlantSpec


class LocalFmuPlant(FmuInstancePlant):
    """The FMU ``spec`` describes, loaded in this process (:func:`bridge.fmu.open_model`).

    Args:
        spec: the model (FMU, interface, time grid, reset policy, solver, parameters, ...) and what
            a sample is; an experiment's from
            :func:`bridge.plant.experiment_model.experiment_plant_spec`.
    """

    def __init__(self, spec: PlantSpec) -> None:
        self.spec = spec
        self.fmu_path = spec.model.fmu
        self.timing = spec.timing
        self.name = spec.named("in-process")
        self.model = open_model(spec.model)
        self.info = self.model.info  # the array sizes after configuration mode
        guard_native_exit()  # an exit() inside the FMU ends the process with code 70, saying so

    def start_from(self, file: StateFile | None, source: str) -> None:
        """Start every episode from the next reset on at ``file``'s saved state; None: as the
        description says (its state file, else initialisation)."""
        own = self.spec.model.state_file
        if file is None and own is not None:
            file, source = state_file.read(own), str(own)
        self.model.start_from(file, source)

    def current_inputs(self) -> list[float]:
        """The input values the FMU holds now (in ``input_names`` order)."""
        return [float(v) for v in self.model.get(self.input_names).values()]
