"""Where a system's macro step can run in one native call (``bridge.fmu.system_step``), and why not.

Serves Jacobi and Gauss-Seidel systems, multi-rate included, whose components are all FMI 2.0/3.0
co-simulation FMUs in this process with Float64 scalar inputs and outputs, whose connections
carry values unchanged or through an affine map (linear transformation and/or unit conversion,
:class:`~bridge.plant.system.transform.Affine`), with or without fixed-point iteration, with
``feedthrough_outputs`` held or updated; ``FMU_BRIDGE_NO_NATIVE`` / ``FMU_BRIDGE_NO_NATIVE_MASTER`` keep the
Python master. :func:`python_master_reason` says why the Python master runs (``system inspect``
shows it). The native call itself, like every FMU call, is made in ``bridge.fmu``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import TYPE_CHECKING

from bridge.errors import BridgeError, FmuError
from bridge.fmu.signals import SignalGroup
from bridge.fmu.system_step import NativeMaster, can_step_natively, library
from bridge.fmu.vocab import ModelInfo
from bridge.plant.base import Plant
from bridge.plant.system.component import FmuComponent
from bridge.plant.system.structure import Connection, SystemDescription
from bridge.plant.system.transform import Affine, Convert

if TYPE_CHECKING:
    from bridge.plant.system.master import Master

__all__ = ["NativeMaster", "native_master", "python_master_reason"]


def python_master_reason(
    system: SystemDescription,
    plants: Mapping[str, Plant],
    couplings: Mapping[Connection, Convert | None],
    infos: Mapping[str, ModelInfo],
) -> str | None:
    """Why the Python master steps this system, from its description alone; None where the native
    master serves it (given a C compiler and instances that hand out their native handles)."""
    if os.environ.get("FMU_BRIDGE_NO_NATIVE") or os.environ.get("FMU_BRIDGE_NO_NATIVE_MASTER"):
        return "FMU_BRIDGE_NO_NATIVE or FMU_BRIDGE_NO_NATIVE_MASTER is set"
    for name, plant in plants.items():
        if not isinstance(plant, FmuComponent):
            node = system.components[name].node
            return f"component {name!r} runs in " + (f"node {node!r}" if node else "a child process")
        if plant.model.interface != "cs" or infos[name].fmi_version.startswith("1."):
            return f"component {name!r} is not an FMI 2.0/3.0 co-simulation FMU"
    for c, convert in couplings.items():
        if convert is not None and not isinstance(convert, Affine):
            return f"connection {c} maps values through a table ({c.transform.kind if c.transform else '?'})"
    for c in system.connections:
        for end in (c.source, c.target):
            var, _ = infos[end.component].element(end.variable)
            if var.type != "Float64":
                return f"connection {c} carries {var.type} values ({end})"
    return None


def native_master(master: Master) -> NativeMaster | None:
    """The native macro step of ``master``, or None where only the Python master serves it."""
    if os.environ.get("FMU_BRIDGE_NO_NATIVE") or os.environ.get("FMU_BRIDGE_NO_NATIVE_MASTER"):
        return None
    if any(k.convert is not None and not isinstance(k.convert, Affine) for k in master.links):
        return None
    groups: dict[str, tuple[SignalGroup | None, SignalGroup]] = {}
    for name, plant in master.plants.items():
        if not isinstance(plant, FmuComponent) or plant.model.interface != "cs" or not plant.output_names:
            return None
        if not can_step_natively(plant.model):
            return None
        handles = plant.model._native_handles()
        if master.iterations > 1 and not all(handles[k] for k in ("get_state", "set_state", "free_state")):
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
