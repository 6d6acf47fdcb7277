"""Where a system's macro step can run in one native call (``bridge.fmu.system_step``).

Serves Jacobi and Gauss-Seidel systems, multi-rate included, whose components are all FMI 2.0/3.0
co-simulation FMUs in this process with Float64 scalar inputs and outputs, whose connections
carry values unchanged (no unit conversion or transformation), without fixed-point iteration
and with ``feedthrough_outputs: held``; ``FMU_BRIDGE_NO_NATIVE`` / ``FMU_BRIDGE_NO_NATIVE_MASTER``
keep the Python master. The native call itself, like every FMU call, is made in ``bridge.fmu``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from bridge.errors import BridgeError, FmuError
from bridge.fmu.signals import SignalGroup
from bridge.fmu.system_step import NativeMaster, can_step_natively, library
from bridge.plant.system.component import FmuComponent

if TYPE_CHECKING:
    from bridge.plant.system.master import Master

__all__ = ["NativeMaster", "native_master"]


def native_master(master: Master) -> NativeMaster | None:
    """The native macro step of ``master``, or None where only the Python master serves it."""
    system = master.system
    if os.environ.get("FMU_BRIDGE_NO_NATIVE") or os.environ.get("FMU_BRIDGE_NO_NATIVE_MASTER"):
        return None
    if master.iterations > 1 or system.feedthrough_outputs != "held" or any(k.convert for k in master.links):
        return None
    groups: dict[str, tuple[SignalGroup | None, SignalGroup]] = {}
    for name, plant in master.plants.items():
        if not isinstance(plant, FmuComponent) or plant.model.interface != "cs" or not plant.output_names:
            return None
        if not can_step_natively(plant.model):
            return None
        try:
            inputs = plant.model.signals(plant.input_names, writable=True) if plant.input_names else None
            outputs = plant.model.signals(plant.output_names)
        except (FmuError, BridgeError):
            return None
        if outputs.native_buffer(writing=False) is None or (
            inputs and inputs.native_buffer(writing=True) is None
        ):
            return None
        groups[name] = (inputs, outputs)
    function = library()
    if function is None:
        return None
    return NativeMaster(master, function, groups, master.external, master.observed)
