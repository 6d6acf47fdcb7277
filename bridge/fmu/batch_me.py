"""Batches of model-exchange instances: one native call integrates a sample of every instance.

``fixed_step_batch`` (``bridge/fmu/fixed_step.c``) sets each active instance's inputs, integrates
its sample with the instance's own fixed-step integrator (``Model.fixed_stepper``: RK4 or Euler)
exactly as the per-instance loop does, and gets its outputs, advancing each model's own clock in
place. An instance that stops at an event, asks to terminate or fails is left where it stopped;
:meth:`MeBatch.finish` then completes its sample through ``Model.me_finish`` (the event iteration
and the rest of the sample, with the same FMI calls as the per-instance path), so trajectories are
identical bit for bit.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.errors import FmuError
from bridge.fmu import native
from bridge.fmu.abi import FAILED, SET_FAILED, FixedBatchSpec
from bridge.fmu.batch_stepper import native_failure

if TYPE_CHECKING:
    from bridge.fmu.model import Model

_SET_OR_GET = range(SET_FAILED, FAILED)  # fixed_step.c: FB_SET / FB_GET + status; 64+: FS_FAILED


class MeBatch:
    """The native sample loop over ``n`` fixed-step model-exchange instances of one FMU.

    Args:
        handles: ``Model.native_handles()`` of the first instance (FMI version, set/get).
        in_vr, out_vr: the value references of the bound inputs and outputs (uint32, kept alive).
        start_time_s, step_size_s, steps: the time grid ``t0 + k h`` and FMU steps per sample.
        substeps: the integrator's steps per FMU step.
        n: instances.
        values: the values of the inputs and of the outputs (FMI 3.0 arrays count every element).
    """

    def __init__(
        self,
        handles: dict[str, int],
        *,
        in_vr: npt.NDArray[np.uint32],
        out_vr: npt.NDArray[np.uint32],
        start_time_s: float,
        step_size_s: float,
        steps: int,
        substeps: int,
        n: int,
        values: tuple[int, int],
    ) -> None:
        self._vrs = (in_vr, out_vr)
        self.spec = FixedBatchSpec(
            handles["major"], handles["set_real"], handles["get_real"], len(in_vr), in_vr.ctypes.data,
            len(out_vr), out_vr.ctypes.data, start_time_s, step_size_s, steps, substeps, *values,
        )  # fmt: skip
        self.steps = steps
        self.specs = np.zeros(n, dtype=np.uintp)
        self.calls = np.zeros(n, dtype=np.uintp)
        self.codes = np.zeros(n, dtype=np.int32)
        # the arrays this object owns keep their addresses: look them up once
        self._own = (ctypes.addressof(self.spec), n, self.specs.ctypes.data, self.calls.ctypes.data)
        self._codes = self.codes.ctypes.data
        p = ctypes.c_void_p
        self._fn = native.load("fixed_step").fixed_step_batch
        self._fn.argtypes = [p, ctypes.c_int, p, p, p, p, p, p, p, ctypes.c_int]
        self._fn.restype = ctypes.c_int

    def bind(self, i: int, model: Model) -> None:
        """Point slot ``i`` at ``model``'s integrator (after every reset: it may be a new one)."""
        stepper = model.fixed_stepper
        if stepper is None:
            raise FmuError(f"{model.info.model_name}: a model-exchange batch needs solver 'rk4' or 'euler'")
        self.specs[i], self.calls[i] = stepper.addresses()

    def step(
        self,
        active: npt.NDArray[np.uint8],
        inputs: npt.NDArray[np.float64],
        outputs: npt.NDArray[np.float64],
        k: npt.NDArray[np.int64],
        threads: int = 1,
    ) -> int:
        """One sample of every active instance over ``threads`` native threads; how many the
        caller must :meth:`finish`."""
        spec, n, specs, calls = self._own
        data = [a.ctypes.data for a in (active, inputs, outputs, k)]
        return int(self._fn(spec, n, specs, calls, *data, self._codes, threads))

    def pending(self) -> list[int]:
        """The instances the last :meth:`step` left for :meth:`finish`."""
        return np.flatnonzero(self.codes > 0).tolist()  # type: ignore[no-any-return]

    def finish(self, i: int, model: Model, names: tuple[Sequence[str], Sequence[str]]) -> bool:
        """Complete instance ``i``'s sample from the model's step (where an event, termination or
        a failure stopped it); True if the FMU asked to terminate.

        Raises:
            FmuError: the set, the get or the integration failed (StepError for the latter).
        """
        code = int(self.codes[i])
        if code in _SET_OR_GET:  # the set (sample not begun) or the get (sample done, k moved) failed
            raise native_failure(model, code, *names)
        return model.me_finish(code, self.steps)
