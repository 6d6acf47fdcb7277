"""``LocalFmuPlant``: one FMU instance in this process (the fastest plant, and what nodes serve).

A step writes the inputs, advances ``n`` FMU steps (``sampling_time = n * h``) and reads the
outputs, in one native call where the FMU allows it (``bridge.fmu.sample``), else through typed
``SignalGroup`` calls; FMU errors become :class:`StepError` with the FMU's own log
(``bridge.plant.instance``, shared with a system's in-process components).
"""

from __future__ import annotations

from bridge.experiment.config import Experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, resolve_state_file, timing
from bridge.fmu import read_model_info, state_file
from bridge.fmu.exit_guard import guard_native_exit
from bridge.fmu.state_file import StateFile
from bridge.plant.experiment_model import experiment_model
from bridge.plant.instance import FmuInstancePlant


class LocalFmuPlant(FmuInstancePlant):
    """The FMU of ``experiment`` (``model.fmu``), loaded and checked in this process.

    Args:
        experiment: the experiment whose ``model`` section says which FMU, interface, step size,
            reset policy and tolerance to use.
    """

    def __init__(self, experiment: Experiment) -> None:
        self.experiment = exp = experiment
        self.fmu_path = resolve_fmu(exp)
        self.info = check_experiment(exp, read_model_info(self.fmu_path))
        self.timing = t = timing(exp, self.info)
        self.name = f"FMU {self.fmu_path.name} (in-process)"
        self.model = experiment_model(exp, self.fmu_path, t)
        guard_native_exit()  # an exit() inside the FMU ends the process with code 70, saying so

    def start_from(self, file: StateFile | None, source: str) -> None:
        """Start every episode from the next reset on at ``file``'s saved state; None: as the
        experiment says (its ``reset_policy: {state_file: ...}``, else initialisation)."""
        if file is None:
            own = resolve_state_file(self.experiment)
            if own is not None:
                file, source = state_file.read(own), str(own)
        self.model.start_from(file, source)

    def current_inputs(self) -> list[float]:
        """The input values the FMU holds now (in ``input_names`` order)."""
        return [float(v) for v in self.model.get(self.input_names).values()]
