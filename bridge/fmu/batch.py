"""``ModelBatch``: N instances of one FMU stepped together, in one native call where it applies.

A step writes every active instance's inputs, advances one sample and reads its outputs. With
the native stepper (``batch.c``, co-simulation) or the fixed-step integrator's batch loop
(``fixed_step.c``, model exchange with solver 'rk4' or 'euler') that is one foreign call for the
whole batch with the GIL released, optionally over several threads; otherwise (no compiler, FMI
1.0, inputs or outputs that are not all Float64 scalars or whole Float64 arrays) the same FMI calls
are made from Python through each ``Model``, with the same results.

The batch keeps no clock of its own: each model's step counter is one cell of :attr:`clock`,
which the native loops advance in place, so ``models[i].time_s`` is instance ``i``'s time
whichever path stepped it. Errors are per instance: a failed instance's :class:`FmuError` is in
the step's ``errors`` and the model refuses to step until it is reset; the others go on.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError, FmuError
from bridge.fmu import batch_stepper
from bridge.fmu.abi import TERMINATED, WARNING, BatchSpec, Clock
from bridge.fmu.batch_me import MeBatch
from bridge.fmu.model import Model
from bridge.fmu.signals import SignalGroup

_log = logging.getLogger(__name__)
FloatArray = npt.NDArray[np.float64]


@dataclass
class BatchOutcome:
    """One batch step: outputs per instance (rows of failed or inactive ones are stale), the
    instances whose FMU asked to terminate, and the errors of the instances that failed."""

    outputs: FloatArray
    terminated: npt.NDArray[np.bool_]
    errors: dict[int, FmuError] = field(default_factory=dict)


class ModelBatch:
    """``models`` (instances of one FMU on one time grid) stepped ``steps_per_sample`` FMU steps a sample.

    Args:
        models: open instances of the same FMU, same interface, step size and start time.
        steps_per_sample: FMU steps per sample.
        threads: native threads stepping the batch (1: the calling thread only).
        native: use a native loop (None: where it can be built and the signals allow it;
            True: raise :class:`ConfigError` where it cannot; False: always Python).
        name: how errors name the batch.
    """

    def __init__(
        self,
        models: Sequence[Model],
        *,
        steps_per_sample: int,
        threads: int = 1,
        native: bool | None = None,
        name: str = "batch",
    ) -> None:
        if not models or threads < 1 or steps_per_sample < 1:
            raise ConfigError(
                f"{name}: a batch needs at least one model, threads >= 1 and steps per sample >= 1, "
                f"got {len(models)} models, threads={threads}, steps_per_sample={steps_per_sample}"
            )
        self.models = list(models)
        self.n, self.steps, self.threads, self.name = len(models), steps_per_sample, threads, name
        self._want_native = native
        self._clock = np.zeros(self.n, dtype=np.int64)
        for i, model in enumerate(self.models):
            model.attach_clock(Clock.from_buffer(self._clock.data, i * self._clock.itemsize))
        self.input_names: tuple[str, ...] = ()
        self.output_names: tuple[str, ...] = ()
        self._inputs: list[SignalGroup] = []
        self._outputs: list[SignalGroup] = []
        self._outputs_buf = np.zeros((self.n, 0))
        self._decided = False
        self._stepper: batch_stepper.NativeStepper | None = None
        self._spec: BatchSpec | None = None
        self._me: MeBatch | None = None
        self._comps = np.zeros(self.n, dtype=np.uintp)
        self._status = np.zeros(self.n, dtype=np.int32)
        self._handles: dict[str, int] = {}

    @property
    def clock(self) -> npt.NDArray[np.int64]:
        """Each instance's FMU steps since the start time: the models' own step counters."""
        return self._clock

    def time_s(self, i: int) -> float:
        """Simulation time of instance ``i``, in seconds."""
        return self.models[i].time_s

    @property
    def native(self) -> bool:
        """Whether steps go through a native loop (known after the first reset)."""
        return self._stepper is not None or self._me is not None

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        """Fix the inputs ``step`` writes and the outputs it returns, in this order."""
        self.input_names, self.output_names = tuple(input_names), tuple(output_names)
        self._inputs = [m.signals(self.input_names, writable=True, role="input") for m in self.models]
        self._outputs = [m.signals(self.output_names, role="output") for m in self.models]
        self._outputs_buf = np.zeros((self.n, len(self.output_names)))

    # -- episodes ---------------------------------------------------------------------------------
    def reset(self, i: int, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        """Reset instance ``i`` with ``values`` (parameters, start values) and ``inputs``; its
        outputs at the start time. Raises :class:`FmuError` where the FMU refuses."""
        model = self.models[i]
        model.reset(values)
        if inputs is not None:
            self._inputs[i].write(inputs)
        outputs = self._outputs[i].read()
        if not self._decided:
            self._decide(model, i)
        if self._me is not None:
            self._check_library(i, model.native_handles())
            self._me.bind(i, model)
        elif self._stepper is not None:
            handles = model.native_handles()
            self._check_library(i, handles)
            self._comps[i] = handles["component"]
        return outputs

    def _check_library(self, i: int, handles: Mapping[str, int]) -> None:
        if any(handles[key] != value for key, value in self._handles.items()):
            raise ConfigError(f"{self.name}: instance {i} loaded another copy of the FMU's library")

    def _decide(self, model: Model, i: int) -> None:
        """Choose the native loop or Python, once, on the first initialised instance (``i``)."""
        self._decided = True
        if self._want_native is False:
            return
        reason = self._native_refusal(model, i)
        stepper = batch_stepper.load() if reason is None and model.interface == "cs" else None
        if reason is None and model.interface == "me":
            self._setup_me(model, i)
            return
        if stepper is None:
            if self._want_native:
                raise ConfigError(f"{self.name}: native stepping is not possible: {reason or 'no compiler'}")
            _log.info("%s: stepping in Python (%s)", self.name, reason or "no native stepper")
            return
        h = model.native_handles()
        self._in_vr, self._out_vr, counts = self._value_references(i)
        self._spec = BatchSpec(
            h["major"], h["set_real"], h["get_real"], h["do_step"], h["bool_status"],
            len(self._in_vr), self._in_vr.ctypes.data, len(self._out_vr), self._out_vr.ctypes.data,
            model.start_time_s, model.step_size_s, self.steps, *counts,
        )  # fmt: skip
        self._handles = {key: value for key, value in h.items() if key != "component"}
        self._stepper = stepper

    def _value_references(
        self, i: int
    ) -> tuple[npt.NDArray[np.uint32], npt.NDArray[np.uint32], tuple[int, int]]:
        """The inputs' and outputs' value references and value counts (FMI 3.0 arrays: one value
        reference, every element a value); _native_refusal checked both layouts exist."""
        (in_vr, nv_in), (out_vr, nv_out) = (
            group[i].float64_layout() or ([], 0) for group in (self._inputs, self._outputs)
        )
        return np.array(in_vr, dtype=np.uint32), np.array(out_vr, dtype=np.uint32), (nv_in, nv_out)

    def _setup_me(self, model: Model, i: int) -> None:
        stepper = model.fixed_stepper
        if stepper is None:  # _native_refusal checked the solver
            raise ConfigError(f"{self.name}: model exchange without a fixed-step solver")
        self._in_vr, self._out_vr, counts = self._value_references(i)
        h = model.native_handles()
        self._handles = {key: h[key] for key in ("major", "set_real", "get_real")}
        self._me = MeBatch(
            h, in_vr=self._in_vr, out_vr=self._out_vr, start_time_s=model.start_time_s,
            step_size_s=model.step_size_s, steps=self.steps, substeps=stepper.substeps, n=self.n,
            values=counts,
        )  # fmt: skip

    def _native_refusal(self, model: Model, i: int) -> str | None:
        info = model.info
        if info.fmi_major < 2 or (model.interface == "me" and model.fixed_stepper is None):
            return (
                f"it needs FMI 2.0/3.0 co-simulation, or model exchange with solver 'rk4' or 'euler'; "
                f"this is FMI {info.fmi_version} {model.interface} (solver {model.solver!r})"
            )
        if model.clocked:
            return "its FMI 3.0 clocks tick in Python (bridge.fmu.clocks)"
        ins, outs = (group[i].float64_layout() for group in (self._inputs, self._outputs))
        if outs is None or (self.input_names and ins is None):
            return (
                f"signals {[*self.input_names, *self.output_names]} are not all Float64 scalars or "
                f"whole Float64 arrays in row-major order"
            )
        discrete = [v.name for v in self._inputs[i].variables if v.variability != "continuous"]
        if model.interface == "me" and discrete:  # they are set in event mode, by the Python path
            return f"model-exchange inputs {discrete} are discrete"
        return None

    # -- stepping ---------------------------------------------------------------------------------
    def step(self, inputs: FloatArray, active: npt.NDArray[np.bool_]) -> BatchOutcome:
        """One sample for every ``active`` instance with ``inputs[i]`` held."""
        if self._me is not None:
            return self._step_me(np.ascontiguousarray(inputs, dtype=np.float64), active)
        if self._stepper is not None:
            return self._step_native(np.ascontiguousarray(inputs, dtype=np.float64), active)
        return self._step_python(inputs, active)

    def _step_python(self, inputs: FloatArray, active: npt.NDArray[np.bool_]) -> BatchOutcome:
        result = BatchOutcome(self._outputs_buf, np.zeros(self.n, dtype=bool))
        for i in np.flatnonzero(active).tolist():
            try:
                self._inputs[i].write(inputs[i])
                result.terminated[i] = self.models[i].advance(self.steps)
                self._outputs[i].read_into(result.outputs[i])
            except FmuError as exc:
                result.errors[i] = exc
        return result

    def _step_native(self, inputs: FloatArray, active: npt.NDArray[np.bool_]) -> BatchOutcome:
        assert self._stepper is not None and self._spec is not None  # step() checked
        status = self._status
        unfinished = self._stepper.step(
            self._spec, comps=self._comps, active=active.view(np.uint8), inputs=inputs,
            outputs=self._outputs_buf, k=self._clock, status=status, threads=self.threads,
        )  # fmt: skip
        terminated = status == TERMINATED
        result = BatchOutcome(self._outputs_buf, terminated)
        if unfinished:  # terminations and failures: rare, accounted in each model
            for i in np.flatnonzero(terminated).tolist():
                self.models[i].terminated = True
            names = (self.input_names, self.output_names)
            for i in np.flatnonzero((status > WARNING) & ~terminated).tolist():
                result.errors[i] = batch_stepper.native_failure(self.models[i], int(status[i]), *names)
        return result

    def _step_me(self, inputs: FloatArray, active: npt.NDArray[np.bool_]) -> BatchOutcome:
        me = self._me
        assert me is not None  # step() checked
        result = BatchOutcome(self._outputs_buf, np.zeros(self.n, dtype=bool))
        if me.step(active.view(np.uint8), inputs, self._outputs_buf, self._clock, threads=self.threads):
            names = (self.input_names, self.output_names)
            for i in me.pending():  # events, termination, failures: finished as one instance would
                try:
                    result.terminated[i] = me.finish(i, self.models[i], names)
                    self._outputs[i].read_into(result.outputs[i])
                except FmuError as exc:
                    result.errors[i] = exc
        return result

    def close(self) -> None:
        """Free every instance (idempotent)."""
        models, self.models = self.models, []
        for model in models:
            model.close()
