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
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError, FmuError
from bridge.fmu import system_step
from bridge.fmu.clock_rules import clock_driver_needed
from bridge.fmu.system_step import Coupling, Happened, Unit
from bridge.fmu.vocab import ModelInfo
from bridge.plant.base import FloatArray, Plant
from bridge.plant.system.component import FmuComponent
from bridge.plant.system.structure import Connection, SystemDescription
from bridge.plant.system.transform import Affine, Convert

if TYPE_CHECKING:
    from bridge.plant.system.master import Link, Master

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
    units = []
    for name in master.order:
        plant = master.plants[name]
        if not isinstance(plant, FmuComponent):  # _component_reason said so already
            return None
        unit, why = _unit(name, plant, master.iterations > 1)
        if unit is None:
            _log.warning("the Python master steps this system: component %r %s", name, why)
            return None
        units.append(unit)
    function = system_step.library()
    if function is None:
        return None
    position = {n: p for p, n in enumerate(master.order)}
    call = system_step.NativeMaster(
        function,
        units,
        [_coupling(link, position) for link in master.links],
        gauss_seidel=master.system.algorithm == "gauss_seidel",
        settle=[position[n] for n in master.settle_order],
        max_iterations=master.iterations,
        tolerance=master.system.tolerance,
        external=[(position[n], j) for n, j in master.external],
        observed=[(position[n], i) for n, i in master.observed],
    )
    return NativeMaster(master, call)


def _unit(name: str, plant: FmuComponent, iterating: bool) -> tuple[Unit | None, str]:
    """``plant`` as the native call steps it; else None and why the call cannot serve it."""
    try:
        inputs = plant.model.signals(plant.input_names, writable=True) if plant.input_names else None
        outputs = plant.model.signals(plant.output_names) if plant.output_names else None
    except (FmuError, BridgeError) as exc:
        return None, f"has signals the native call cannot take ({exc})"
    unit = Unit(name, plant.model, inputs, outputs, plant.timing.steps_per_sample)
    if not system_step.usable(unit, iterating):
        return None, (
            "cannot be stepped natively (its native handles, its FMU state functions for "
            "fixed-point iteration, or inputs that cannot be set during a step)"
        )
    return unit, ""


def _coupling(link: Link, position: Mapping[str, int]) -> Coupling:
    """A master's link as the native call reads it; its conversion is None or an :class:`Affine`."""
    ends = (position[link.source], link.i, position[link.target], link.j)
    if link.convert is None:
        return Coupling(*ends)
    convert: Any = link.convert
    return Coupling(*ends, convert.factor, convert.offset, affine=True)


class NativeMaster:
    """The master's macro steps as native calls (``bridge.fmu.system_step``), with the plant's
    bookkeeping: each component's sample count and terminated flag, and a failure raised as the
    Python master raises it (each component's own call says why). Call :meth:`refresh` after
    every initialisation."""

    def __init__(self, master: Master, call: system_step.NativeMaster) -> None:
        self.master, self._call = master, call
        self._names = list(master.order)
        self._plants: list[FmuComponent] = [master.plants[n] for n in self._names]  # type: ignore[misc]
        self.done = 0  # macro steps the last call completed
        self.stopped = False  # whether a component asked to stop in the last call

    def refresh(self) -> None:
        """Hand the master's arrays to the native call again (instances and arrays may be new)."""
        master, self.stopped = self.master, False
        inputs, outputs = self._call.bind(
            [master.inputs[n] for n in self._names], [master.outputs[n] for n in self._names]
        )
        for name, u, y in zip(self._names, inputs, outputs, strict=True):
            master.inputs[name], master.outputs[name] = u, y

    def sample(self, inputs: Sequence[float] | None, count: int) -> FloatArray:
        """Set the task's ``inputs`` (None: keep the last), step up to ``count`` macro steps and
        return the observation (a new array): :meth:`run` with the task's ends, in one call."""
        call = self._call
        observation = call.sample(inputs, count)
        if observation is None:  # a component cannot step: its own refusal, as the Python path raises it
            if inputs is not None:
                call.stage(inputs)
            self._refused(inputs is not None)
            raise BridgeError(
                f"the system: a component cannot step, and did not say why{self.master.system.where}"
            )
        happened = call.happened
        if call.iterating:
            self._iterations()
        if happened.done == count and not happened.failed and not happened.stopped:
            self.done = count
            for plant in self._plants:
                plant.sample += count
            return observation
        self.done, self.stopped = happened.done, happened.stopped
        self._finish(happened)
        return observation

    def run(self, count: int) -> None:
        """Up to ``count`` macro steps in one call (fewer when a component asks to stop: then it is
        terminated); :attr:`done` says how many completed, also when one fails, which raises the
        component's own error (as the Python master)."""
        if self._call.refused() is not None:
            self._refused(False)
        happened = self._call.run(count)
        if self._call.iterating:
            self._iterations()
        self.done = happened.done
        if happened.failed or happened.stopped:
            self.stopped = happened.stopped
            self._finish(happened)
            return
        for plant in self._plants:
            plant.sample += happened.done

    def _iterations(self) -> None:
        """The master's iteration counts, as its Python loop keeps them."""
        call = self._call
        self.master.last_iterations = call.last_iterations
        self.master.unconverged_steps += call.unconverged
        call.unconverged = 0

    def _refused(self, with_inputs: bool) -> None:
        """The Python path raises the model's own refusal (terminated, failed, closed)."""
        if with_inputs:  # the task's inputs are where the Python path would have put them
            for position, j, value in self._call.staged():
                self.master.inputs[self._names[position]][j] = value
        for name, plant in zip(self._names, self._plants, strict=True):
            if not plant.model.steppable:
                self.done = 0
                plant.step(self.master.inputs[name].tolist())

    def _finish(self, happened: Happened) -> None:
        failed, done = happened.failed, happened.done
        for position, plant in enumerate(self._plants):
            plant.sample += done - (1 if not failed else 0)
            if position < happened.stepped:
                plant.native_done()
        if failed:
            self._fail(failed - 1, happened)

    def _fail(self, position: int, happened: Happened) -> None:
        plant, name = self._plants[position], self._names[position]
        inputs = self.master.inputs[name].tolist()
        if happened.during == "state":  # the FMU refused to save or restore its state: its own call says why
            state = plant.save()
            plant.restore(state)
            plant.discard(state)
            raise plant._failed(
                FmuError(
                    f"{plant.name}: the FMU state could not be saved or restored "
                    f"(status {happened.status}) during fixed-point iteration"
                )
            )
        if happened.during == "settling":  # set or get while settling: the Python path's own call says why
            plant.settle(inputs)
        if happened.nonfinite:  # the Python path's own check names the input
            plant.step(inputs)
        plant.native_failed(happened.status)
