"""FMUs: the model vocabulary (``vocab``, no FMPy) and the FMU runtime (the only FMPy importer).

Every call into an FMU is made here: ``Model`` (one instance, its clock, resets and states; its
runtime and the one interface native steppers use are ``instance.Instance``), ``ModelBatch`` (N
instances stepped in one native call), the one-call native sample (``sample``), the system's
native master (``system_step``: models, links and buffers, no plant), FMI 3.0 clocks and
scheduled execution (``clocks``) and the C helpers (``batch.c``, ``fixed_step.c``, ``master.c``)
with their ctypes mirrors and the FMI status codes in one module (``abi``).
FMI names (camelCase, value references, status codes) and ctypes stop here; everything above
speaks in variable names, numpy arrays and seconds (pyproject.toml's import contracts enforce it).
``bridge.fmu.vocab`` (variables, model info, their JSON form) imports nothing heavy, so the task,
the remote plant and the deployed agent use it without loading FMPy; the names below load the
runtime on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from bridge.fmu.vocab import DefaultExperiment, ModelInfo, Variable

if TYPE_CHECKING:
    from bridge.fmu.archive import sha256
    from bridge.fmu.batch import BatchOutcome, ModelBatch
    from bridge.fmu.description import read_model_info
    from bridge.fmu.model import RESET_POLICIES, Model, ModelState
    from bridge.fmu.opening import open_model
    from bridge.fmu.signals import SignalGroup
    from bridge.fmu.spec import ModelSpec, ResetPolicy

_RUNTIME = {
    "sha256": "bridge.fmu.archive",
    "BatchOutcome": "bridge.fmu.batch",
    "ModelBatch": "bridge.fmu.batch",
    "read_model_info": "bridge.fmu.description",
    "RESET_POLICIES": "bridge.fmu.model",
    "Model": "bridge.fmu.model",
    "ModelState": "bridge.fmu.model",
    "ResetPolicy": "bridge.fmu.spec",
    "SignalGroup": "bridge.fmu.signals",
    "ModelSpec": "bridge.fmu.spec",
    "open_model": "bridge.fmu.opening",
}

__all__ = [
    "RESET_POLICIES",
    "BatchOutcome",
    "DefaultExperiment",
    "Model",
    "ModelBatch",
    "ModelInfo",
    "ModelSpec",
    "ModelState",
    "ResetPolicy",
    "SignalGroup",
    "Variable",
    "open_model",
    "read_model_info",
    "sha256",
]


def __getattr__(name: str) -> Any:
    """The runtime's names, imported (with FMPy) on first use."""
    module = _RUNTIME.get(name)
    if module is None:
        raise AttributeError(f"module 'bridge.fmu' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
