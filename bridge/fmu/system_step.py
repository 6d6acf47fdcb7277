"""A system's macro step in one native call (``master.c``), for systems it can serve exactly.

Serves Jacobi and Gauss-Seidel systems, multi-rate included, whose components are all FMI 2.0/3.0
co-simulation FMUs in this process with Float64 scalar inputs and outputs, whose connections
carry values unchanged (no unit conversion or transformation), without fixed-point iteration
and with ``feedthrough_outputs: held``. Everything else, or a machine without a C compiler, or
``FMU_BRIDGE_NO_NATIVE`` / ``FMU_BRIDGE_NO_NATIVE_MASTER`` set, keeps the Python master, which stays
the reference: the native call makes the FMI calls the Python master makes over each component's
native sample, in the same order with the same arguments, so the trajectories are equal bit for
bit (tests/plant/test_system_native_master.py). ctypes releases the GIL during the call.

The library is built with gcc on first use and cached like the batch stepper's
(``bridge.fmu.native``). Its inputs and outputs are the master's own arrays: the C code sets the
FMU inputs from ``Master.inputs[name]`` and gets the outputs into ``Master.outputs[name]``.
``bridge.plant.system.native_master`` decides where it applies; this module makes the calls.
Each component's step counter travels in its C struct for the call and back into its model.
"""

from __future__ import annotations

import ctypes
import logging
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from bridge.errors import BridgeError, FmuError
from bridge.fmu import native as native_build
from bridge.fmu.abi import NONFINITE, TERMINATED, MasterComponent, MasterLink
from bridge.fmu.model import Model
from bridge.fmu.signals import SignalGroup

if TYPE_CHECKING:
    from bridge.plant.system.component import FmuComponent
    from bridge.plant.system.master import Master

_log = logging.getLogger(__name__)
_Component, _Link = MasterComponent, MasterLink


@lru_cache(maxsize=1)
def library() -> Any:
    """``master_run`` of ``master.c``, built on first use; None where it cannot be built."""
    try:
        library = native_build.load("master")
    except BridgeError as exc:
        _log.warning("native system master unavailable, stepping in Python instead: %s", exc)
        return None
    function = library.master_run
    p, i = ctypes.c_void_p, ctypes.c_int
    function.argtypes = [p, i, p, i, i, p, i, p]
    function.restype = ctypes.c_int
    return function


def can_step_natively(model: Model) -> bool:
    """Whether ``model`` is an initialised FMI 2.0/3.0 instance a native loop can call."""
    try:
        model._native_handles()
    except FmuError:
        return False
    return True


class NativeMaster:
    """The macro step of ``master`` in one call; build with :func:`native_master` (None where it
    does not apply). Call :meth:`refresh` after every initialisation (instances and the master's
    arrays may be new)."""

    def __init__(
        self, master: Master, function: Any, groups: dict[str, tuple[SignalGroup | None, SignalGroup]]
    ) -> None:
        self.master, self._call, self._groups = master, function, groups
        self._names = list(master.order)
        self._plants: list[FmuComponent] = [master.plants[n] for n in self._names]  # type: ignore[misc]
        position = {n: p for p, n in enumerate(self._names)}
        links = [_Link(position[k.source], k.i, position[k.target], k.j) for k in master.links]
        self._links = (_Link * max(1, len(links)))(*links)
        self._n_links = len(links)
        self._comps = (_Component * len(self._names))()
        self._status = (ctypes.c_int * len(self._names))()
        self._gauss_seidel = int(master.system.algorithm == "gauss_seidel")
        self._accounts = [(p, p.model, c) for p, c in zip(self._plants, self._comps)]
        address = ctypes.addressof
        self._args = (
            ctypes.c_void_p(address(self._comps)),
            len(self._names),
            ctypes.c_void_p(address(self._links)),
            self._n_links,
            self._gauss_seidel,
            ctypes.c_void_p(address(self._status)),
        )
        self._done = ctypes.c_int(0)
        self._done_ref = ctypes.byref(self._done)
        self.done = 0  # macro steps the last call completed

    def refresh(self) -> None:
        """Re-read the instances' addresses and the master's arrays (after a reset)."""
        master = self.master
        for c, (name, plant) in zip(self._comps, zip(self._names, self._plants)):
            model, (inputs, outputs) = plant.model, self._groups[name]
            h = model._native_handles()
            c.major, c.set_real, c.get_real = h["major"], h["set_real"], h["get_real"]
            c.do_step, c.bool_status, c.component = h["do_step"], h["bool_status"], h["component"]
            c.t0, c.h, c.steps = model.start_time_s, model.step_size_s, plant.timing.steps_per_sample
            c.k = model.step_index  # kept here from now on; each step hands it to the model
            c.n_in, c.nv_in, c.in_vr = 0, 0, None
            if inputs is not None:
                vrs, c.n_in, c.nv_in, _ = inputs.native_buffer(writing=True) or (0, 0, 0, 0)
                c.in_vr = vrs
            master.inputs[name] = u = np.ascontiguousarray(master.inputs[name], dtype=np.float64)
            master.outputs[name] = y = np.ascontiguousarray(master.outputs[name], dtype=np.float64).copy()
            c.u, c.y = u.ctypes.data, y.ctypes.data
            c.out_vr, c.n_out, c.nv_out, _ = outputs.native_buffer(writing=False) or (0, 0, 0, 0)

    def run(self, count: int) -> None:
        """Up to ``count`` macro steps in one call (fewer when a component asks to stop: then its
        ``terminated`` is set); :attr:`done` says how many completed, also when one fails, which
        raises the component's own error (as the Python master)."""
        plants, comps, status = self._plants, self._comps, self._status
        for name, plant in zip(self._names, plants):
            if not plant.model._steppable:  # the Python path raises the model's own refusal
                self.done = 0
                plant.step(self.master.inputs[name].tolist())
        failed = self._call(*self._args, count, self._done_ref)
        self.done = done = self._done.value
        if not failed and not any(status):  # the hot path: every component stepped with OK
            for plant, model, c in self._accounts:
                model.step_index = c.k
                plant.sample += done
            return
        stepped = len(comps)  # components that took part in the last macro step tried
        if failed:
            stepped = failed - 1
            if status[stepped] == NONFINITE and not self._gauss_seidel:
                stepped = 0  # Jacobi checks every input before any component steps
        for position, (plant, model, c) in enumerate(self._accounts):
            model.step_index = c.k
            plant.sample += done - (1 if not failed else 0)
            if position < stepped:
                plant.native_done(c.k, status[position] == TERMINATED)
        if failed:
            self._fail(plants[failed - 1], status[failed - 1], comps[failed - 1].k)

    def _fail(self, plant: FmuComponent, status: int, k: int) -> None:
        name = self._names[self._plants.index(plant)]
        if status == NONFINITE:  # the Python path's own check names the input
            plant.step(self.master.inputs[name].tolist())
        plant.native_failed(status, k)
