"""The Gymnasium side: one env that runs a ``Task`` over any plant, rendering, and the ids of
the bundled examples.

May import every lower package (plant, task, experiment, fmu through the in-process plant);
only the CLI imports it.
"""

from bridge.env.fmu_env import FmuEnv, as_experiment, make
from bridge.env.node_vector import NodeVectorEnv
from bridge.env.remote import RemoteFmuEnv
from bridge.env.vec import PlantVecEnv, RemoteVecEnv

__all__ = ["FmuEnv", "NodeVectorEnv", "PlantVecEnv", "RemoteFmuEnv", "RemoteVecEnv", "as_experiment", "make"]
