"""Nodes built from an experiment or a system file: composition above the network.

A node (``bridge.net.node.FmuNode``) serves a plant and the names it serves: a
:class:`~bridge.plant.spec.PlantSpec` and a :class:`~bridge.net.served.Served`. This package
builds both from the files users write: :mod:`bridge.serving.experiment` for an experiment (the
names its task reads and drives, the values its resets may set), :mod:`bridge.serving.system` for
the components of a system served by nodes. It reads the task's names here, so that the network
never imports the task.

May import the network, the task, plants and the experiment; never the env or the CLI.
"""

from bridge.serving.experiment import experiment_node, served_by
from bridge.serving.system import (
    ServedComponent,
    component_served,
    component_signals,
    serve_components,
    served_components,
    start_nodes,
)

__all__ = [
    "ServedComponent",
    "component_served",
    "component_signals",
    "experiment_node",
    "serve_components",
    "served_by",
    "served_components",
    "start_nodes",
]
