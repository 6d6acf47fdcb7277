"""An experiment's FMU plant, and what its model is without starting it (variables, fingerprint).

:func:`fmu_plant` is the one place that chooses between an FMU in this process and one in a
child process: envs (``bridge.env.plants.plant_for``, which adds systems over the network) and
nodes (``bridge.net.node``) both get their plant here."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge.experiment.config import Experiment
from bridge.experiment.system import is_system_file
from bridge.fmu import read_model_info
from bridge.fmu.vocab import ModelInfo
from bridge.plant.spec import Isolation, PlantSpec

if TYPE_CHECKING:
    from bridge.plant.base import Plant
    from bridge.plant.system.plant import RemoteComponents


def fmu_plant(spec: PlantSpec, *, isolate: bool = False, timeout_s: float | None = None) -> Plant:
    """The FMU ``spec`` describes, in a child process when ``spec.isolation`` or ``isolate`` asks
    for it (bounded by the isolation's ``timeout_s``, else ``timeout_s``, else 10 s) or the FMU
    needs a process of its own, else in this process. ``plant.isolated`` says which.

    The plant checks no task: the env checks it once against ``plant.info``."""
    isolation = spec.isolation
    if isolation is None and isolate:
        isolation = Isolation(timeout_s or 10.0)
    if isolation is None and _needs_own_process(read_model_info(spec.model.fmu)):
        isolation = Isolation()
    if isolation is not None:
        from bridge.plant.isolated import IsolatedFmuPlant

        return IsolatedFmuPlant(
            spec,
            timeout_s=isolation.timeout_s,
            memory_limit_mb=isolation.memory_limit_mb,
            restart=isolation.restart,
        )
    from bridge.plant.local import LocalFmuPlant  # the FMU runtime only when it runs here

    return LocalFmuPlant(spec)


def experiment_plant(
    experiment: Experiment, *, isolate: bool = False, timeout_s: float | None = None
) -> Plant:
    """The plant of the experiment's FMU (:func:`fmu_plant` of its ``model`` section's description)."""
    from bridge.plant.experiment_model import experiment_plant_spec

    return fmu_plant(experiment_plant_spec(experiment), isolate=isolate, timeout_s=timeout_s)


def _needs_own_process(info: ModelInfo) -> bool:
    """canBeInstantiatedOnlyOncePerProcess: each instance gets a process of its own, so that
    several envs, a vector env or a system never share the FMU's global state. Python-backed FMUs
    (pythonfmu, pythonfmu3) and FMUs that need an execution tool: their teardown may abort, crash
    or hang after a correct run, which must not decide the exit status of the process that ran
    them."""
    return info.once_per_process or info.python_backed or info.needs_execution_tool


def is_system(experiment: Experiment) -> bool:
    """Whether the experiment couples several FMUs (a ``system:`` section or an .ssp/.ssd)."""
    return experiment.system is not None or is_system_file(experiment.model.fmu)


def model_info_for(experiment: Experiment, remote: RemoteComponents | None = None) -> ModelInfo:
    """What the experiment's plant serves (the FMU's variables, or a system's ``component.variable``
    ones) without starting it; ``remote`` describes a system's components whose FMU is only on
    their node's machine (``bridge.env.plants.model_info_for`` passes the network's)."""
    if is_system(experiment):
        from bridge.plant.system.plant import describe_system

        return describe_system(experiment, remote)
    from bridge.experiment.validate import configured, resolve_fmu
    from bridge.fmu import read_model_info

    return configured(experiment, read_model_info(resolve_fmu(experiment)))


def model_fingerprint(experiment: Experiment, remote: RemoteComponents | None = None) -> tuple[str, str]:
    """The model file and its SHA-256; for a system, its description and the hash of its FMUs'
    hashes (a node's FMU that is not here: the hash its node reports, through ``remote``)."""
    from bridge.fmu import sha256

    if is_system(experiment):
        from bridge.plant.system.description import from_experiment
        from bridge.plant.system.plant import system_checksum

        source = from_experiment(experiment).source
        return str(source or ""), system_checksum(experiment, remote)
    from bridge.experiment.validate import resolve_fmu

    fmu = resolve_fmu(experiment)
    return str(fmu), sha256(fmu)
