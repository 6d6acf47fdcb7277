"""Where a system's macro step can run in one native call (``bridge.fmu.system_step``), and why not.

Serves Jacobi and Gauss-Seidel systems, multi-rate included, whose components are all FMI 2.0/3.0
co-simulation FMUs in this process without input clocks, with inputs and outputs of any numeric
type (Float, Int, Boolean, Enumeration; FMI 3.0 arrays whole or in part), whose connections
carry values unchanged or through an affine map (linear transformation and/or unit conversion,
:class:`~bridge.plant.system.transform.Affine`), with or without fixed-point iteration, with
``feedthrough_outputs`` held or updated; ``FMU_BRIDGE_NO_NATIVE`` / ``FMU_BRIDGE_NO_NATIVE_MASTER`` keep the
Python master. :func:`python_master_reason` says why the Python master runs (``system inspect``
shows it). The native call itself, like every FMU call, is made in ``bridge.fmu``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError, FmuError
from bridge.fmu.clock_rules import clock_driver_needed
from bridge.fmu.master_io import servable
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

_log = logging.getLogger(__name__)


def python_master_reason(
    system: SystemDescription,
    plants: Mapping[str, Plant],
    couplings: Mapping[Connection, Convert | None],
    infos: Mapping[str, ModelInfo],
) -> str | None:
    """Why the Python master steps this system, from its description alone; None where the native
    master serves it (given a C compiler and instances that hand out their native handles).

    Every numeric variable may be connected, driven by the task or observed, whatever its type
    (Float32/64, the integer types, Boolean, Enumeration) and whether an FMI 3.0 array is used whole
    or in part: the native call converts and checks them as the signal groups do."""
    return _setting_reason() or _component_reason(system, plants, infos) or _table_reason(couplings.items())


def _setting_reason() -> str | None:
    if os.environ.get("FMU_BRIDGE_NO_NATIVE") or os.environ.get("FMU_BRIDGE_NO_NATIVE_MASTER"):
        return "FMU_BRIDGE_NO_NATIVE or FMU_BRIDGE_NO_NATIVE_MASTER is set"
    return None


def _component_reason(
    system: SystemDescription, plants: Mapping[str, Plant], infos: Mapping[str, ModelInfo]
) -> str | None:
    for name, plant in plants.items():
        if not isinstance(plant, FmuComponent):
            node = system.components[name].node
            return f"component {name!r} runs in " + (f"node {node!r}" if node else "a child process")
        interface = plant.model.interface
        if interface != "cs" or infos[name].fmi_version.startswith("1."):
            return f"component {name!r} is not an FMI 2.0/3.0 co-simulation FMU"
        if clock_driver_needed(infos[name], interface):
            return f"component {name!r} has input clocks, which tick in Python (bridge.fmu.clocks)"
    return None


def _table_reason(couplings: Iterable[tuple[Any, Convert | None]]) -> str | None:
    for c, convert in couplings:
        if convert is not None and not isinstance(convert, Affine):
            kind = c.transform.kind if getattr(c, "transform", None) else "?"
            return f"connection {c} maps values through a table ({kind})"
    return None


def native_master(master: Master) -> NativeMaster | None:
    """The native macro step of ``master``, or None where only the Python master serves it (for
    the reasons :func:`python_master_reason` names, which it shares)."""
    infos = {n: p.info for n, p in master.plants.items() if isinstance(p, FmuComponent)}
    links = ((f"{k.source} -> {k.target}", k.convert) for k in master.links)
    if _setting_reason() or _component_reason(master.system, master.plants, infos) or _table_reason(links):
        return None
    groups: dict[str, tuple[SignalGroup | None, SignalGroup | None]] = {}
    for name, plant in master.plants.items():
        if not isinstance(plant, FmuComponent):  # _component_reason said so already
            return None
        why = _groups(name, plant, master.iterations > 1, groups)
        if why:
            _log.warning("the Python master steps this system: component %r %s", name, why)
            return None
    function = library()
    if function is None:
        return None
    return NativeMaster(master, function, groups, master.external, master.observed)


def _groups(
    name: str,
    plant: FmuComponent,
    iterating: bool,
    groups: dict[str, tuple[SignalGroup | None, SignalGroup | None]],
) -> str | None:
    """Binds ``plant``'s signal groups into ``groups``; else why the native call cannot serve it."""
    if not can_step_natively(plant.model):
        return "cannot be stepped natively"
    handles = plant.model._native_handles()
    if iterating and not all(handles[k] for k in ("get_state", "set_state", "free_state")):
        return "has no FMU state functions for fixed-point iteration"
    try:
        inputs = plant.model.signals(plant.input_names, writable=True) if plant.input_names else None
        outputs = plant.model.signals(plant.output_names) if plant.output_names else None
    except (FmuError, BridgeError) as exc:
        return f"has signals the native call cannot take ({exc})"
    if not servable(inputs, outputs):
        return "has inputs that cannot be set during a step"
    groups[name] = (inputs, outputs)
    return None
