"""One sample of one FMU instance in one native call: set the inputs, doStep, get the outputs.

The Python path makes three foreign calls per sample (set, doStep, get), and each ctypes call
costs about a microsecond of argument conversion, more than a small FMU's doStep itself. The
batch stepper's C helper (``bridge/fmu/batch.c``, ``step_one``) makes the same FMI calls, in the
same order, with the same arguments and the same time grid ``t0 + k*h``, in one, and advances
the model's own clock in place.

It serves initialised FMI 2.0/3.0 co-simulation instances whose inputs and outputs are all
Float64 scalars (the common case) or whole Float64 arrays in row-major order (one value reference
and all its elements: ``nValues`` counts them); anything else, or a machine without a C compiler, takes the
Python path, with the same results (tests/plant/test_native_sample.py compares both).
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence

from bridge.errors import FmuError
from bridge.fmu import batch_stepper as nat
from bridge.fmu.abi import TERMINATED, WARNING, BatchSpec
from bridge.fmu.model import Model
from bridge.fmu.signals import FloatArray, SignalGroup


def sample_failure(
    model: Model, status: int, input_names: Sequence[str], output_names: Sequence[str]
) -> FmuError:
    """The error of a native sample of ``model`` that ended in ``status`` (above Warning, not a
    termination) at its current step: as :class:`NativeSample` raises it, for the system's native
    master (``bridge.fmu.system_step``), whose samples make the same calls."""
    return nat.native_failure(model, status, input_names, output_names)


class NativeSample:
    """``sample(inputs) -> outputs`` for one model; ``terminated`` after each call.

    Build with :meth:`create`, which returns None where the native path does not apply.
    Call :meth:`refresh` after anything that may re-instantiate the FMU (a reset).
    """

    terminated = False

    def __init__(
        self,
        stepper: nat.NativeStepper,
        model: Model,
        inputs: SignalGroup | None,
        outputs: SignalGroup,
        steps_per_sample: int,
    ) -> None:
        self._model, self._inputs, self._outputs = model, inputs, outputs
        self._n = steps_per_sample
        self._call = stepper.step_one
        self._spec = BatchSpec()
        self._refs = (ctypes.byref(self._spec), ctypes.byref(model.clock))
        self._u: int | None = None
        self._y: int | None = None
        self._component = ctypes.c_void_p(0)
        self._bound: tuple[object, object] | None = None  # the instance and the clock bound
        self.refresh()

    @classmethod
    def create(
        cls, model: Model, inputs: SignalGroup | None, outputs: SignalGroup | None, steps_per_sample: int
    ) -> NativeSample | None:
        if model.interface != "cs" or outputs is None or outputs.native_buffer(writing=False) is None:
            return None
        if inputs is not None and inputs.native_buffer(writing=True) is None:
            return None
        try:
            model.native_handles()
        except FmuError:  # FMI 1.0, not initialised: the Python path serves it
            return None
        stepper = nat.load()
        return cls(stepper, model, inputs, outputs, steps_per_sample) if stepper is not None else None

    def refresh(self) -> None:
        """Re-read the instance's function and component addresses (after a reset); nothing to
        do where the reset kept the instance (restore, fmi reset): a reset stays cheap."""
        model = self._model
        bound = self._bound
        if bound is not None and bound[0] is model.backend.component and bound[1] is model.clock:
            return
        h = model.native_handles()
        self._bound = (model.backend.component, model.clock)
        spec = self._spec
        spec.major, spec.set_real, spec.get_real = h["major"], h["set_real"], h["get_real"]
        spec.do_step, spec.bool_status = h["do_step"], h["bool_status"]
        spec.t0, spec.h, spec.steps = model.start_time_s, model.step_size_s, self._n
        spec.n_in, spec.nv_in, spec.in_vr, self._u = 0, 0, None, None
        if self._inputs is not None:
            vrs, n, values, self._u = self._inputs.native_buffer(writing=True) or (0, 0, 0, None)
            spec.n_in, spec.nv_in, spec.in_vr = n, values, vrs
        out = self._outputs.native_buffer(writing=False)
        assert out is not None  # checked in create()
        spec.out_vr, spec.n_out, spec.nv_out, self._y = out
        self._component.value = h["component"]
        self._refs = (self._refs[0], ctypes.byref(model.clock))

    def __call__(self, inputs: Sequence[float] | None) -> FloatArray:
        model = self._model
        if not model.steppable:
            model.advance(self._n)  # raises the model's own refusal (terminated, failed, closed)
        if inputs is not None and self._inputs is not None:
            self._inputs.stage(inputs)
        spec_ref, k_ref = self._refs
        status = self._call(spec_ref, self._component, self._u, self._y, k_ref)
        self.terminated = False
        if status > WARNING:
            if status != TERMINATED:
                raise nat.native_failure(
                    model, status, self._inputs.names if self._inputs is not None else (), self._outputs.names
                )
            model.terminated = True
            self.terminated = True
        return self._outputs.latest()
