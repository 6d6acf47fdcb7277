"""Batches of model-exchange instances: one native call integrates a sample of every instance.

``fixed_step_batch`` (``bridge/fmu/fixed_step.c``) sets each active instance's inputs, integrates
its sample with the instance's own fixed-step integrator (``Model.fixed_stepper``: RK4 or Euler)
exactly as the per-instance loop does, and gets its outputs. An instance that stops at an event,
asks to terminate or fails is left where it stopped; :meth:`MeBatch.finish` then completes its
sample through ``Model.native_me_finish`` (the event iteration and the rest of the sample, with
the same FMI calls as the per-instance path), so trajectories are identical bit for bit.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.fmu import native
from bridge.plant.batch import native as nat

if TYPE_CHECKING:
    from bridge.experiment.validate import Timing
    from bridge.fmu import Model

_SET_OR_GET = range(nat.SET_FAILED, 64)  # fixed_step.c: FB_SET / FB_GET + status; 64+: FS_FAILED


class FixedBatchSpec(ctypes.Structure):
    """The C ``FixedBatch``: FMI version, Float64 set/get, value references, the time grid."""

    _fields_ = [
        ("major", ctypes.c_int),
        ("set_real", ctypes.c_void_p),
        ("get_real", ctypes.c_void_p),
        ("n_in", ctypes.c_int),
        ("in_vr", ctypes.c_void_p),
        ("n_out", ctypes.c_int),
        ("out_vr", ctypes.c_void_p),
        ("t0", ctypes.c_double),
        ("h", ctypes.c_double),
        ("steps", ctypes.c_int),
        ("substeps", ctypes.c_int),
    ]


class MeBatch:
    """The native sample loop over ``n`` fixed-step model-exchange instances of one FMU.

    Args:
        handles: ``Model.native_handles()`` of the first instance (FMI version, set/get).
        in_vr, out_vr: the value references of the bound inputs and outputs (uint32, kept alive).
        timing: the experiment's timing (FMU step, steps per sample, start time).
        substeps: the integrator's steps per FMU step.
        n: instances.
    """

    def __init__(
        self,
        handles: dict[str, int],
        *,
        in_vr: npt.NDArray[np.uint32],
        out_vr: npt.NDArray[np.uint32],
        timing: Timing,
        substeps: int,
        n: int,
    ) -> None:
        self._vrs = (in_vr, out_vr)
        self.spec = FixedBatchSpec(
            handles["major"], handles["set_real"], handles["get_real"], len(in_vr), in_vr.ctypes.data,
            len(out_vr), out_vr.ctypes.data, timing.start_time_s, timing.step_size_s,
            timing.steps_per_sample, substeps,
        )  # fmt: skip
        self.steps = timing.steps_per_sample
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
        assert stepper is not None  # BatchPlant checks the solver before it builds a MeBatch
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

    def finish(
        self, i: int, model: Model, k: npt.NDArray[np.int64], names: tuple[Sequence[str], Sequence[str]]
    ) -> bool:
        """Complete instance ``i``'s sample from step ``k[i]`` (an event, termination or a failure)
        and move ``k[i]`` to where the model stands; True if the FMU asked to terminate.

        Raises:
            FmuError: the set, the get or the integration failed (StepError for the latter).
        """
        code = int(self.codes[i])
        if code in _SET_OR_GET:  # the set (sample not begun) or the get (sample done, k moved) failed
            raise nat.native_failure(model, code, int(k[i]), *names)
        try:
            return model.native_me_finish(code, int(k[i]), self.steps)
        finally:
            k[i] = model.step_index
