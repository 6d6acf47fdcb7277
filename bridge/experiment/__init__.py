"""Experiment files: the typed configuration (``config``), its checks against a model
(``validate``), starting files written from an FMU (``init``) and the bundled examples.

May import the model vocabulary (``bridge.fmu.vocab``) and, where a file names an FMU, the FMU
runtime's readers (``bridge.fmu``, loaded on first use) and the example models (``bridge.models``);
never the plants, the task, the env, the network or recording.
"""

from bridge.experiment.config import Experiment, load_experiment, parse_experiment

__all__ = ["Experiment", "load_experiment", "parse_experiment"]
