"""A system's macro step in one native call (``master.c``), for systems it can serve exactly.

Serves Jacobi and Gauss-Seidel systems, multi-rate included, whose components are all FMI 2.0/3.0
co-simulation FMUs in this process with numeric inputs and outputs of any type (``master_io``
binds them), whose connections
carry values unchanged or through an affine map (linear transformation, unit conversion),
with or without fixed-point iteration (FMU states saved, restored and freed in the call, as the
Python master does through each component), with ``feedthrough_outputs`` held or updated (the
feedthrough components settled in the same call, as the Python master settles them). Everything
else, or a
machine without a C compiler, or ``FMU_BRIDGE_NO_NATIVE`` / ``FMU_BRIDGE_NO_NATIVE_MASTER`` set,
keeps the Python master, which stays the reference: the native call makes the FMI calls the
Python master makes over each component's native sample, in the same order with the same
arguments, so the trajectories are equal bit for bit (tests/plant/test_system_native_master.py).
ctypes releases the GIL during the call.

The library is built with gcc on first use and cached like the batch stepper's
(``bridge.fmu.native``). Its inputs and outputs are the master's own arrays: the C code sets the
FMU inputs from ``Master.inputs[name]`` and gets the outputs into ``Master.outputs[name]``.
The same call scatters the task's inputs into those arrays first and gathers the observed outputs
into one observation buffer after, so a sample of the system is one call and no allocation but the
observation's copy. ``bridge.plant.system.native_master`` decides where it applies; this module
makes the calls. Each model's step counter is a cell of an array the C code advances in place.
"""

from __future__ import annotations

import ctypes
import logging
from collections.abc import Sequence
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from bridge.errors import BridgeError, FmuError
from bridge.fmu import native as native_build
from bridge.fmu.abi import (
    NONFINITE,
    SETTLING,
    STATE,
    TERMINATED,
    Clock,
    MasterComponent,
    MasterLink,
    MasterSample,
)
from bridge.fmu.master_io import bind_signals
from bridge.fmu.model import Model
from bridge.fmu.signals import SignalGroup

if TYPE_CHECKING:
    from bridge.plant.system.component import FmuComponent
    from bridge.plant.system.master import Master

_log = logging.getLogger(__name__)
_Component, _Link = MasterComponent, MasterLink


@lru_cache(maxsize=1)
def library() -> Any:
    """``master_sample`` of ``master.c``, built on first use; None where it cannot be built."""
    try:
        library = native_build.load("master")
    except BridgeError as exc:
        _log.warning("native system master unavailable, stepping in Python instead: %s", exc)
        return None
    function = library.master_sample
    # (Sample*, int count, int with_inputs), always called with a byref and two Python ints: without
    # argtypes ctypes passes those as they are, which halves the call's cost (about 0.6 us)
    function.restype = ctypes.c_int
    return function


def can_step_natively(model: Model) -> bool:
    """Whether ``model`` is an initialised FMI 2.0/3.0 instance a native loop can call."""
    try:
        model._native_handles()
    except FmuError:
        return False
    return True


def _link(link: Any, position: dict[str, int]) -> MasterLink:
    """A master's link as ``master.c`` reads it; its conversion is None or an affine map (both
    with ``factor`` and ``offset``), which ``native_master`` checked."""
    ends = (position[link.source], link.i, position[link.target], link.j)
    if link.convert is None:
        return _Link(*ends, 1.0, 0.0, 0)
    return _Link(*ends, link.convert.factor, link.convert.offset, 1)


def _ints(values: Sequence[int]) -> np.ndarray[Any, np.dtype[np.intc]]:
    return np.ascontiguousarray(np.array(list(values) or [0], dtype=np.intc))


class NativeMaster:
    """The macro step of ``master`` in one call; build with :func:`native_master` (None where it
    does not apply). Call :meth:`refresh` after every initialisation (instances and the master's
    arrays may be new).

    ``external`` and ``observed`` are the task's inputs and observed outputs as (component,
    position) in the master's input and output arrays: :meth:`sample` sets the first and returns
    the second."""

    def __init__(
        self,
        master: Master,
        function: Any,
        groups: dict[str, tuple[SignalGroup | None, SignalGroup | None]],
        external: Sequence[tuple[str, int]] = (),
        observed: Sequence[tuple[str, int]] = (),
    ) -> None:
        self.master, self._call, self._groups = master, function, groups
        self._names = list(master.order)
        self._plants: list[FmuComponent] = [master.plants[n] for n in self._names]  # type: ignore[misc]
        position = {n: p for p, n in enumerate(self._names)}
        links = [_link(k, position) for k in master.links]
        self._links = (_Link * max(1, len(links)))(*links)
        self._comps = (_Component * len(self._names))()
        self._status = (ctypes.c_int * len(self._names))()
        self._gauss_seidel = int(master.system.algorithm == "gauss_seidel")
        self._clocks = np.zeros(len(self._names), dtype=np.int64)  # each model's k, advanced in C
        self._models = [p.model for p in self._plants]
        self._pairs = list(zip(self._plants, self._models))
        self._ext_comp = _ints([position[n] for n, _ in external])
        self._ext_j = _ints([j for _, j in external])
        self._obs_comp = _ints([position[n] for n, _ in observed])
        self._obs_i = _ints([i for _, i in observed])
        self._ext = np.zeros(max(1, len(external)))
        self._ext_view = self._ext[: len(external)]
        self._ext_c = (ctypes.c_double * len(external)).from_buffer(self._ext.data)
        self._obs = np.zeros(len(observed))
        self._obs_buffer = np.zeros(max(1, len(observed)))  # C writes here; :meth:`sample` copies
        self._spec = spec = MasterSample()
        address = ctypes.addressof
        spec.comps, spec.n = address(self._comps), len(self._names)
        spec.links, spec.n_links = address(self._links), len(links)
        spec.gauss_seidel, spec.status = self._gauss_seidel, address(self._status)
        spec.n_ext, spec.ext = len(external), self._ext.ctypes.data
        spec.ext_comp, spec.ext_j = self._ext_comp.ctypes.data, self._ext_j.ctypes.data
        spec.n_obs, spec.obs = len(observed), self._obs_buffer.ctypes.data
        spec.obs_comp, spec.obs_i = self._obs_comp.ctypes.data, self._obs_i.ctypes.data
        self._settle = _ints([position[n] for n in master.settle_order])
        spec.n_settle, spec.settle = len(master.settle_order), self._settle.ctypes.data
        n = len(self._names)
        self._states = (ctypes.c_void_p * n)()
        self._saved_k = np.zeros(n, dtype=np.int64)
        self._used: list[Any] = []
        self._iterating = master.iterations > 1
        iteration = spec.iteration
        iteration.max_iterations, iteration.tolerance = master.iterations, master.system.tolerance
        iteration.states, iteration.saved_k = ctypes.addressof(self._states), self._saved_k.ctypes.data
        self._spec_ref = ctypes.byref(spec)
        self._n_obs, self._n_ext = len(observed), len(external)
        self.done = 0  # macro steps the last call completed
        self.stopped = False  # whether a component asked to stop in the last call

    def refresh(self) -> None:
        """Re-read the instances' addresses and the master's arrays (after a reset)."""
        master, self.stopped = self.master, False
        self._used = []
        for position, (c, name, plant) in enumerate(zip(self._comps, self._names, self._plants)):
            model, (inputs, outputs) = plant.model, self._groups[name]
            h = model._native_handles()
            c.major, c.set_real, c.get_real = h["major"], h["set_real"], h["get_real"]
            c.do_step, c.bool_status, c.component = h["do_step"], h["bool_status"], h["component"]
            c.t0, c.h, c.steps = model.start_time_s, model.step_size_s, plant.timing.steps_per_sample
            model._attach_clock(Clock.from_buffer(self._clocks.data, position * self._clocks.itemsize))
            c.k = self._clocks.ctypes.data + position * self._clocks.itemsize
            master.inputs[name] = u = np.ascontiguousarray(master.inputs[name], dtype=np.float64)
            master.outputs[name] = y = np.ascontiguousarray(master.outputs[name], dtype=np.float64).copy()
            c.u, c.y = u.ctypes.data, y.ctypes.data
            self._used += bind_signals(c, inputs, outputs, len(u), len(y))  # kept alive with the rest
            c.get_state, c.set_state, c.free_state = h["get_state"], h["set_state"], h["free_state"]
            self._used.append(used := np.zeros(max(1, len(u))))  # alive while C writes into it
            c.used = used.ctypes.data

    def sample(self, inputs: Sequence[float] | None, count: int) -> np.ndarray[Any, np.dtype[np.float64]]:
        """Set the task's ``inputs`` (None: keep the last), step up to ``count`` macro steps and
        return the observation (a new array): :meth:`run` with the task's ends, in one call."""
        with_inputs = 0 if inputs is None else 1
        if inputs is not None:
            try:
                if inputs.__class__ is list:  # ctypes copies a list faster, numpy an array
                    self._ext_c[:] = inputs
                else:
                    self._ext_view[:] = inputs
            except (ValueError, TypeError) as exc:
                raise BridgeError(
                    f"the system's inputs: expected {self._n_ext} numbers, got {len(inputs)} ({exc}); "
                    f"pass one number per action input, in the order of actions.inputs"
                ) from None
        for plant, m in self._pairs:  # Model._steppable inlined, and the sample counted ahead
            if not m._initialized or m.terminated or m._failed_status or m._closed:
                for counted in self._plants[: self._plants.index(plant)]:
                    counted.sample -= count
                self._refused(with_inputs)
            plant.sample += count
        code = self._call(self._spec_ref, count, with_inputs)
        if self._iterating:
            self._count_iterations()
        if not code:  # every component stepped `count` macro steps with OK
            self.done = count
            obs: np.ndarray[Any, np.dtype[np.float64]] = (
                self._obs_buffer.copy() if self._n_obs else self._obs.copy()
            )
            return obs
        spec = self._spec
        self.done = done = spec.done
        self.stopped = bool(spec.stopped)
        for plant in self._plants:
            plant.sample -= count
        self._finish(max(code, 0), done)
        obs = self._obs_buffer.copy() if self._n_obs else self._obs.copy()
        return obs

    def run(self, count: int) -> None:
        """Up to ``count`` macro steps in one call (fewer when a component asks to stop: then its
        ``terminated`` is set); :attr:`done` says how many completed, also when one fails, which
        raises the component's own error (as the Python master)."""
        for m in self._models:
            if not m._steppable:
                self._refused(0)
        code = self._call(self._spec_ref, count, 0)
        if self._iterating:
            self._count_iterations()
        self.done = done = self._spec.done
        if code:
            self.stopped = bool(self._spec.stopped)
            self._finish(max(code, 0), done)
            return
        for plant in self._plants:
            plant.sample += done

    def _count_iterations(self) -> None:
        """The master's iteration counts, as its Python loop keeps them."""
        iteration = self._spec.iteration
        self.master.last_iterations = iteration.last
        self.master.unconverged_steps += iteration.unconverged
        iteration.unconverged = 0

    def _refused(self, with_inputs: int) -> None:
        """The Python path raises the model's own refusal (terminated, failed, closed)."""
        if with_inputs:  # the task's inputs are where the Python path would have put them
            inputs = self.master.inputs
            for e in range(self._spec.n_ext):
                name = self._names[int(self._ext_comp[e])]
                inputs[name][int(self._ext_j[e])] = self._ext[e]
        for name, plant in zip(self._names, self._plants):
            if not plant.model._steppable:
                self.done = 0
                plant.step(self.master.inputs[name].tolist())

    def _finish(self, failed: int, done: int) -> None:
        plants, status = self._plants, self._status
        stepped = len(plants)  # components that took part in the last macro step tried
        if failed and status[failed - 1] < SETTLING:  # a settling failure: every component stepped
            stepped = failed - 1
        for position, plant in enumerate(plants):
            plant.sample += done - (1 if not failed else 0)
            if position < stepped:
                plant.native_done(int(self._clocks[position]), status[position] == TERMINATED)
        if failed:
            self._fail(plants[failed - 1], status[failed - 1], int(self._clocks[failed - 1]))

    def _fail(self, plant: FmuComponent, status: int, k: int) -> None:
        name = self._names[self._plants.index(plant)]
        inputs = self.master.inputs[name].tolist()
        if status >= STATE:  # the FMU refused to save or restore its state: its own call says why
            state = plant.save()
            plant.restore(state)
            plant.discard(state)
            raise plant._failed(
                FmuError(
                    f"{plant.name}: the FMU state could not be saved or restored "
                    f"(status {status - STATE}) during fixed-point iteration"
                )
            )
        if status >= SETTLING:  # set or get while settling: the Python path's own call says why
            plant.settle(inputs)
            status -= SETTLING
        if status == NONFINITE:  # the Python path's own check names the input
            plant.step(inputs)
        plant.native_failed(status, k)
