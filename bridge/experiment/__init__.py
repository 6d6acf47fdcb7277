"""Experiment files: the typed configuration (``config``), its checks against a model
(``validate``), starting files written from an FMU (``init``) and the bundled examples.

May import ``bridge.plant`` (the model vocabulary); never the FMU runtime at import time, the
task, the env, the network or recording.
"""

from bridge.experiment.config import Experiment, load_experiment, parse_experiment

__all__ = ["Experiment", "load_experiment", "parse_experiment"]
