"""The native batch stepper: ``batch.c`` (next to this module) built with gcc on first use, bound with ctypes.

The library is built and cached by ``bridge.fmu.native`` (keyed by source, FMI headers and
compiler flags, moved into the per-user cache atomically). ctypes releases the GIL for the
duration of a foreign call, so other Python threads run while the batch steps.

``load()`` returns None (and logs why) when there is no compiler: the caller then steps with
the pure-Python path, which gives the same results.
"""

from __future__ import annotations

import ctypes
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, FmuError
from bridge.fmu import native as native_build
from bridge.fmu.abi import GET_FAILED, SET_FAILED, BatchSpec, status_name

if TYPE_CHECKING:
    from bridge.fmu.model import Model

_log = logging.getLogger(__name__)


@dataclass
class NativeStepper:
    """``batch_step``, ``step_one`` and ``batch_do_steps`` of the loaded library."""

    library: ctypes.CDLL

    def __post_init__(self) -> None:
        p = ctypes.c_void_p
        self._step = self.library.batch_step
        self._step.argtypes = [p, ctypes.c_int, p, p, p, p, p, p, ctypes.c_int]
        self._step.restype = ctypes.c_int
        self._do_steps = self.library.batch_do_steps
        self._do_steps.argtypes = [p, ctypes.c_int, p, p, ctypes.c_int]
        self._do_steps.restype = ctypes.c_int
        self.step_one = self.library.step_one
        """``step_one(spec, component, inputs, outputs, k)``: one sample of one instance."""
        self.step_one.argtypes = [p, p, p, p, p]
        self.step_one.restype = ctypes.c_int

    def step(
        self,
        spec: BatchSpec,
        *,
        comps: npt.NDArray[np.uintp],
        active: npt.NDArray[np.uint8],
        inputs: npt.NDArray[np.float64],
        outputs: npt.NDArray[np.float64],
        k: npt.NDArray[np.int64],
        status: npt.NDArray[np.int32],
        threads: int = 1,
    ) -> int:
        """One sample for every active instance (arrays C-contiguous); how many did not succeed."""
        return int(
            self._step(
                ctypes.addressof(spec),
                len(comps),
                comps.ctypes.data,
                active.ctypes.data,
                inputs.ctypes.data,
                outputs.ctypes.data,
                k.ctypes.data,
                status.ctypes.data,
                threads,
            )
        )

    def do_steps(
        self, spec: BatchSpec, comps: npt.NDArray[np.uintp], k: npt.NDArray[np.int64], samples: int
    ) -> int:
        """``samples`` samples of doStep calls only, over every instance (the benchmark's floor)."""
        return int(
            self._do_steps(ctypes.addressof(spec), len(comps), comps.ctypes.data, k.ctypes.data, samples)
        )


@lru_cache(maxsize=1)
def load() -> NativeStepper | None:
    """The native stepper, built on first use; None when it cannot be built (no gcc, no headers)
    or ``FMU_BRIDGE_NO_NATIVE`` is set: the caller then steps from Python, with the same results."""
    if os.environ.get("FMU_BRIDGE_NO_NATIVE"):
        return None
    try:
        return NativeStepper(native_build.load("batch"))
    except BridgeError as exc:
        _log.warning("native batch stepping unavailable, stepping in Python instead: %s", exc)
        return None


def native_failure(
    model: Model, status: int, input_names: Sequence[str], output_names: Sequence[str]
) -> FmuError:
    """The error for a native sample of ``model`` that ended in ``status`` (above Warning, not
    TERMINATED) at its current step: a failed set or get names the variables, a failed doStep
    is accounted in the model (which then refuses to step until reset) and carries its message."""
    if status >= SET_FAILED:
        what, names = ("get", output_names) if status >= GET_FAILED else ("set", input_names)
        return FmuError(
            f"{model.info.model_name}: {what} of {list(names)} returned {status_name(status & 15)} "
            f"at step {model.step_index} (t={model.time_s:g} s)",
            log=model.log,
        )
    try:
        model.native_step_failed(status)
    except FmuError as exc:
        return exc
    return FmuError(f"doStep returned {status_name(status)}", log=model.log)
