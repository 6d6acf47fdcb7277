"""``plant_for``: the plant an experiment asks for when no plant is given."""

from __future__ import annotations

import hashlib

from bridge.experiment.config import Experiment
from bridge.experiment.system import is_system_file
from bridge.fmu.vocab import ModelInfo
from bridge.plant.base import Plant


def is_system(experiment: Experiment) -> bool:
    """Whether the experiment couples several FMUs (a ``system:`` section or an .ssp/.ssd)."""
    return experiment.system is not None or is_system_file(experiment.model.fmu)


def plant_for(experiment: Experiment) -> Plant:
    """A :class:`SystemPlant` for a system; the FMU in a child process where ``model.isolation``
    asks for it (``IsolatedFmuPlant``); else the FMU in this process (``LocalFmuPlant``)."""
    if is_system(experiment):
        from bridge.plant.system.plant import SystemPlant

        return SystemPlant(experiment)
    isolation = experiment.model.isolation
    if isolation is not None:
        from bridge.plant.isolated import IsolatedFmuPlant

        return IsolatedFmuPlant(
            experiment,
            timeout_s=isolation.timeout,
            memory_limit_mb=isolation.memory_limit_mb,
            restart=isolation.restart,
        )
    from bridge.plant.local import LocalFmuPlant  # the FMU runtime only when it runs here

    return LocalFmuPlant(experiment)


def model_info_for(experiment: Experiment) -> ModelInfo:
    """What the experiment's plant serves (the FMU's variables, or a system's ``component.variable``
    ones) without starting it."""
    if is_system(experiment):
        from bridge.plant.system.plant import describe_system

        return describe_system(experiment)
    from bridge.experiment.validate import resolve_fmu
    from bridge.fmu import read_model_info

    return read_model_info(resolve_fmu(experiment))


def model_fingerprint(experiment: Experiment) -> tuple[str, str]:
    """The model file and its SHA-256; for a system, its description and the hash of its FMUs' hashes."""
    from bridge.fmu import sha256

    if is_system(experiment):
        from bridge.plant.system.description import from_experiment

        system = from_experiment(experiment)
        joined = "\n".join(f"{n}:{sha256(c.fmu)}" for n, c in system.components.items())
        return str(system.source or ""), hashlib.sha256(joined.encode()).hexdigest()
    from bridge.experiment.validate import resolve_fmu

    fmu = resolve_fmu(experiment)
    return str(fmu), sha256(fmu)
