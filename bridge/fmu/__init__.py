"""The FMU runtime: the only package of fmu-bridge that imports FMPy.

FMI names (camelCase, value references, status codes) stop here; everything above speaks
in variable names, numpy arrays and seconds.
"""

from __future__ import annotations

from bridge.fmu.archive import sha256
from bridge.fmu.description import DefaultExperiment, ModelInfo, Variable, read_model_info
from bridge.fmu.model import RESET_POLICIES, Model, ResetPolicy
from bridge.fmu.signals import SignalGroup

__all__ = [
    "RESET_POLICIES",
    "DefaultExperiment",
    "Model",
    "ModelInfo",
    "ResetPolicy",
    "SignalGroup",
    "Variable",
    "read_model_info",
    "sha256",
]
