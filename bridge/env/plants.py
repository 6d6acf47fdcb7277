"""``plant_for``: the plant an experiment asks for when the env is given none.

Here rather than in ``bridge.plant`` because a system's components may be nodes: the env layer
may use the network, plants may not.
"""

from __future__ import annotations

from bridge.experiment.config import Experiment
from bridge.fmu.vocab import ModelInfo
from bridge.plant import factory
from bridge.plant.base import Plant
from bridge.plant.factory import is_system


def plant_for(experiment: Experiment) -> Plant:
    """A :class:`SystemPlant` for a system (node components over Zenoh); the FMU in a child
    process where ``model.isolation`` asks for it or the FMU declares
    ``canBeInstantiatedOnlyOncePerProcess`` (so that any number of envs over it each have their own
    process and globals); else the FMU in this process."""
    if is_system(experiment):
        from bridge.net.system_node import NodeComponents
        from bridge.plant.system.plant import SystemPlant

        return SystemPlant(experiment, remote=NodeComponents())
    return factory.experiment_plant(experiment)


def model_info_for(experiment: Experiment) -> ModelInfo:
    """What the experiment's plant serves, without starting it (``bridge.plant.factory``); a
    system's component whose FMU is only on its node's machine is described by its node."""
    if not is_system(experiment):
        return factory.model_info_for(experiment)
    from bridge.net.system_node import NodeComponents

    remote = NodeComponents()  # opens a session only if a node must be asked
    try:
        return factory.model_info_for(experiment, remote)
    finally:
        remote.close()


def model_fingerprint(experiment: Experiment) -> tuple[str, str]:
    """The model file and its SHA-256 (``bridge.plant.factory``), a node's FMU by its node's hash."""
    if not is_system(experiment):
        return factory.model_fingerprint(experiment)
    from bridge.net.system_node import NodeComponents

    remote = NodeComponents()
    try:
        return factory.model_fingerprint(experiment, remote)
    finally:
        remote.close()
