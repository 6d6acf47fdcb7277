"""``plant_for``: the plant an experiment asks for when the env is given none.

Here rather than in ``bridge.plant`` because a system's components may be nodes: the env layer
may use the network, plants may not.
"""

from __future__ import annotations

from bridge.experiment.config import Experiment
from bridge.plant.base import Plant
from bridge.plant.factory import is_system


def plant_for(experiment: Experiment) -> Plant:
    """A :class:`SystemPlant` for a system (node components over Zenoh); the FMU in a child
    process where ``model.isolation`` asks for it; else the FMU in this process."""
    if is_system(experiment):
        from bridge.net.system_node import NodeComponents
        from bridge.plant.system.plant import SystemPlant

        return SystemPlant(experiment, remote=NodeComponents())
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
