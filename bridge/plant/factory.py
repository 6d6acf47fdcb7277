"""``plant_for``: the plant an experiment asks for when no plant is given."""

from __future__ import annotations

from bridge.experiment.config import Experiment
from bridge.experiment.system import is_system_file
from bridge.plant.base import Plant


def is_system(experiment: Experiment) -> bool:
    """Whether the experiment couples several FMUs (a ``system:`` section or an .ssp/.ssd)."""
    return experiment.system is not None or is_system_file(experiment.model.fmu)


def plant_for(experiment: Experiment) -> Plant:
    """A :class:`SystemPlant` for a system, else the FMU in this process (``LocalFmuPlant``)."""
    if is_system(experiment):
        from bridge.plant.system.plant import SystemPlant

        return SystemPlant(experiment)
    from bridge.plant.local import LocalFmuPlant  # the FMU runtime only when it runs here

    return LocalFmuPlant(experiment)
