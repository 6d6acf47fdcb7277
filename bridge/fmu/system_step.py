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
(``bridge.fmu.native``). This module knows models, links and buffers, no plant: :class:`NativeMaster`
takes the components' models with their signal groups (:class:`Unit`), the links as array positions
(:class:`Coupling`) and, after every initialisation, the master's input and output arrays, which
the C code reads and writes in place (it sets the FMU inputs from ``inputs[c]`` and gets the
outputs into ``outputs[c]``). The same call scatters the task's inputs into those arrays first
and gathers the observed outputs into one observation buffer after, so a sample of the system is
one call and no allocation but the observation's copy. Each call returns what happened
(:class:`Happened`); the plant's master (``bridge.plant.system.native_master``) decides where the
native call applies and keeps its own bookkeeping (samples, errors). Each model's step counter is
a cell of an array the C code advances in place.
"""

from __future__ import annotations

import ctypes
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

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
from bridge.fmu.master_io import bind_signals, servable
from bridge.fmu.model import Model
from bridge.fmu.signals import SignalGroup

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
        model.native_handles()
    except FmuError:
        return False
    return True


@dataclass(frozen=True)
class Coupling:
    """A link as array positions: output ``i`` of component ``source`` feeds input ``j`` of
    ``target``, as it is or (``affine``) as ``factor * value + offset``."""

    source: int
    i: int
    target: int
    j: int
    factor: float = 1.0
    offset: float = 0.0
    affine: bool = False


@dataclass(frozen=True)
class Unit:
    """One component as the native master steps it: its model, the signal groups of its inputs
    (None: it has none) and outputs, and its FMU steps per macro step."""

    name: str
    model: Model
    inputs: SignalGroup | None
    outputs: SignalGroup | None  # None: a component the master only drives
    steps: int


@dataclass(frozen=True)
class Happened:
    """What a call did. ``done``: macro steps every component completed; ``stopped``: a component
    asked to stop; ``failed``: 0, or 1 + the position of the component whose call failed with FMI
    ``status``, ``during`` its ``"step"``, a ``"settling"`` set or get, saving or restoring its
    ``"state"``, and ``nonfinite`` where an input was not finite; ``stepped``: the components that
    took part in the macro step tried last (they stand after it)."""

    done: int
    stopped: bool = False
    failed: int = 0
    status: int = 0
    during: str = "step"
    nonfinite: bool = False
    stepped: int = 0


def usable(unit: Unit, iterating: bool) -> bool:
    """Whether the native call can step ``unit``: an initialised FMI 2.0/3.0 co-simulation instance
    whose signals the call can set and get, of any numeric type (``master_io``; and, when
    ``iterating``, whose FMU states can be saved)."""
    model = unit.model
    if model.interface != "cs" or not can_step_natively(model):
        return False
    handles = model.native_handles()
    if iterating and not all(handles[k] for k in ("get_state", "set_state", "free_state")):
        return False
    return servable(unit.inputs, unit.outputs)


def _ints(values: Sequence[int]) -> np.ndarray[Any, np.dtype[np.intc]]:
    return np.ascontiguousarray(np.array(list(values) or [0], dtype=np.intc))


class NativeMaster:
    """The macro step of a system's components in one call; build with the function of
    :func:`library`. Call :meth:`bind` after every initialisation (instances and arrays may be new).

    ``external`` and ``observed`` are the task's inputs and observed outputs as (component
    position, position) in the input and output arrays: :meth:`sample` sets the first and returns
    the second. ``settle`` lists the positions of the components settled after each exchange."""

    def __init__(
        self,
        function: Any,
        units: Sequence[Unit],
        couplings: Sequence[Coupling],
        *,
        gauss_seidel: bool,
        settle: Sequence[int] = (),
        max_iterations: int = 1,
        tolerance: float = 0.0,
        external: Sequence[tuple[int, int]] = (),
        observed: Sequence[tuple[int, int]] = (),
    ) -> None:
        self._call, self.units = function, list(units)
        self._models = [u.model for u in self.units]
        n = len(self.units)
        links = [_Link(c.source, c.i, c.target, c.j, c.factor, c.offset, int(c.affine)) for c in couplings]
        self._links = (_Link * max(1, len(links)))(*links)
        self._comps = (_Component * n)()
        self._status = (ctypes.c_int * n)()
        self._gauss_seidel = int(gauss_seidel)
        self._clocks = np.zeros(n, dtype=np.int64)  # each model's k, advanced in C
        self._ext_comp = _ints([c for c, _ in external])
        self._ext_j = _ints([j for _, j in external])
        self._obs_comp = _ints([c for c, _ in observed])
        self._obs_i = _ints([i for _, i in observed])
        self._ext = np.zeros(max(1, len(external)))
        self._ext_view = self._ext[: len(external)]
        self._ext_c = (ctypes.c_double * len(external)).from_buffer(self._ext.data)
        self._obs = np.zeros(len(observed))
        self._obs_buffer = np.zeros(max(1, len(observed)))  # C writes here; :meth:`sample` copies
        self._spec = spec = MasterSample()
        address = ctypes.addressof
        spec.comps, spec.n = address(self._comps), n
        spec.links, spec.n_links = address(self._links), len(links)
        spec.gauss_seidel, spec.status = self._gauss_seidel, address(self._status)
        spec.n_ext, spec.ext = len(external), self._ext.ctypes.data
        spec.ext_comp, spec.ext_j = self._ext_comp.ctypes.data, self._ext_j.ctypes.data
        spec.n_obs, spec.obs = len(observed), self._obs_buffer.ctypes.data
        spec.obs_comp, spec.obs_i = self._obs_comp.ctypes.data, self._obs_i.ctypes.data
        self._settle = _ints(settle)
        spec.n_settle, spec.settle = len(settle), self._settle.ctypes.data
        self._states = (ctypes.c_void_p * n)()
        self._saved_k = np.zeros(n, dtype=np.int64)
        self._used: list[Any] = []
        self.iterating = max_iterations > 1
        iteration = spec.iteration
        iteration.max_iterations, iteration.tolerance = max_iterations, tolerance
        iteration.states, iteration.saved_k = ctypes.addressof(self._states), self._saved_k.ctypes.data
        self._spec_ref = ctypes.byref(spec)
        self._n_obs, self._n_ext = len(observed), len(external)
        self._done_ok: dict[int, Happened] = {}
        self.happened = Happened(0)  # what the last sample did
        self.last_iterations = 0  # passes made in the last macro step (iterating)
        self.unconverged = 0  # macro steps that did not converge since the last look (iterating)

    def bind(self, inputs: Sequence[Any], outputs: Sequence[Any]) -> tuple[list[Any], list[Any]]:
        """Re-read the instances' addresses and take each component's input and output array (after
        every initialisation); returns the arrays the C code now reads and writes, in place of
        those given (contiguous float64; the outputs a copy), for the master to keep."""
        used_in, used_out, self._used = [], [], []
        for position, (c, unit) in enumerate(zip(self._comps, self.units, strict=True)):
            model = unit.model
            h = model.native_handles()
            c.major, c.set_real, c.get_real = h["major"], h["set_real"], h["get_real"]
            c.do_step, c.bool_status, c.component = h["do_step"], h["bool_status"], h["component"]
            c.t0, c.h, c.steps = model.start_time_s, model.step_size_s, unit.steps
            model.attach_clock(Clock.from_buffer(self._clocks.data, position * self._clocks.itemsize))
            c.k = self._clocks.ctypes.data + position * self._clocks.itemsize
            u = np.ascontiguousarray(inputs[position], dtype=np.float64)
            y = np.ascontiguousarray(outputs[position], dtype=np.float64).copy()
            used_in.append(u)
            used_out.append(y)
            c.u, c.y = u.ctypes.data, y.ctypes.data
            self._used += bind_signals(c, unit.inputs, unit.outputs, len(u), len(y))  # kept alive
            c.get_state, c.set_state, c.free_state = h["get_state"], h["set_state"], h["free_state"]
            self._used.append(used := np.zeros(max(1, len(u))))  # alive while C writes into it
            c.used = used.ctypes.data
        return used_in, used_out

    def refused(self) -> int | None:
        """The position of the first component that cannot step now (terminated, failed, closed),
        or None: the call would step every one."""
        for position, model in enumerate(self._models):
            if not model.steppable:
                return position
        return None

    def stage(self, inputs: Sequence[float]) -> None:
        """Set the task's ``inputs`` for the next :meth:`sample`."""
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

    def staged(self) -> list[tuple[int, int, float]]:
        """The task's staged inputs as (component position, input position, value)."""
        return [
            (int(self._ext_comp[e]), int(self._ext_j[e]), float(self._ext[e])) for e in range(self._n_ext)
        ]

    def sample(
        self, inputs: Sequence[float] | None, count: int
    ) -> np.ndarray[Any, np.dtype[np.float64]] | None:
        """Set the task's ``inputs`` (None: keep the last), step up to ``count`` macro steps and
        return the observation (a new array), with what happened in :attr:`happened`; None, with
        nothing called, where a component cannot step (:meth:`refused`). No tuple is built: one
        more allocation per sample makes the garbage collector run measurably more often."""
        for m in self._models:  # Instance.steppable inlined: a property call per model costs more here
            if not m.initialized or m.terminated or m.failed_status or m.closed:
                return None
        with_inputs = 0
        if inputs is not None:
            with_inputs = 1
            try:
                if inputs.__class__ is list:  # ctypes copies a list faster, numpy an array
                    self._ext_c[:] = inputs
                else:
                    self._ext_view[:] = inputs
            except (ValueError, TypeError):
                self.stage(inputs)  # raises, saying what was expected
        code = self._call(self._spec_ref, count, with_inputs)
        if self.iterating:
            self._count_iterations()
        obs: np.ndarray[Any, np.dtype[np.float64]] = (
            self._obs_buffer.copy() if self._n_obs else self._obs.copy()
        )
        # every component stepped `count` macro steps with OK, or what stopped the call
        self.happened = (self._done_ok.get(count) or self._ok(count)) if not code else self._happened(code)
        return obs

    def run(self, count: int) -> Happened:
        """Up to ``count`` macro steps in one call (fewer when a component asks to stop: then its
        model's ``terminated`` is set); every component must be steppable (:meth:`refused`)."""
        code = self._call(self._spec_ref, count, 0)
        if self.iterating:
            self._count_iterations()
        if not code:
            return self._ok(self._spec.done)
        return self._happened(code)

    def _ok(self, done: int) -> Happened:
        """``Happened(done)``, made once per count: building a frozen dataclass costs about a
        microsecond, as much as the rest of a small system's sample."""
        happened = self._done_ok.get(done)
        if happened is None:
            happened = self._done_ok[done] = Happened(done)
        return happened

    def _count_iterations(self) -> None:
        iteration = self._spec.iteration
        self.last_iterations = iteration.last
        self.unconverged += iteration.unconverged
        iteration.unconverged = 0

    def _happened(self, code: int) -> Happened:
        """A call that stopped early: which components stepped, and the models that terminated."""
        spec, status = self._spec, self._status
        failed = max(code, 0)
        stepped = len(self._models)  # components that took part in the last macro step tried
        if failed and status[failed - 1] < SETTLING:  # a settling failure: every component stepped
            stepped = failed - 1
        for position in range(stepped):
            if status[position] == TERMINATED:
                self._models[position].terminated = True
        code = status[failed - 1] if failed else 0
        during = "state" if code >= STATE else "settling" if code >= SETTLING else "step"
        code -= STATE if code >= STATE else SETTLING if code >= SETTLING else 0
        nonfinite = during != "state" and code == NONFINITE
        return Happened(spec.done, bool(spec.stopped), failed, code, during, nonfinite, stepped)
