"""What the stepping of one instance needs besides the instance: its FMI functions' addresses for
the native steppers, and the errors of a failed or refused step.

The native steppers of this package (``sample``, ``batch``, ``system_step``) call an instance's
FMI functions directly, from C; :func:`function_addresses` hands them out, one dict per instance.
"""

from __future__ import annotations

from typing import Any

from bridge.errors import StepError
from bridge.fmu.abi import STATUS_NAMES, address, pointer_value
from bridge.fmu.description import ModelInfo


def function_addresses(backend: Any) -> dict[str, int]:
    """Addresses for a native stepper that calls the instance of ``backend`` (a
    :class:`~bridge.fmu.backend.Backend`, FMI 2.0/3.0, instantiated) directly.

    Keys: ``component`` (the instance), ``major`` (FMI version), ``set_real``, ``get_real``,
    ``do_step`` and ``bool_status`` (the Float64 set/get, doStep and, for FMI 2.0,
    fmi2GetBooleanStatus; 0 where absent), ``get_state``, ``set_state``, ``free_state`` (the FMU
    state functions; 0 where absent).
    """
    major, functions = backend.major, backend.functions
    v, real = f"fmi{major}", "Real" if major == 2 else "Float64"
    return {
        "component": pointer_value(backend.component),
        "major": major,
        "set_real": address(functions.get(f"{v}Set{real}")),
        "get_real": address(functions.get(f"{v}Get{real}")),
        "do_step": address(functions.get(f"{v}DoStep")),
        "bool_status": address(functions.get("fmi2GetBooleanStatus")) if major == 2 else 0,
        # a system's fixed-point iteration saves and restores the state natively
        "get_state": address(functions.get("fmi2GetFMUstate" if major == 2 else "fmi3GetFMUState")),
        "set_state": address(functions.get("fmi2SetFMUstate" if major == 2 else "fmi3SetFMUState")),
        "free_state": address(functions.get("fmi2FreeFMUstate" if major == 2 else "fmi3FreeFMUState")),
    }


def step_failed(info: ModelInfo, status: int, *, k: int, time_s: float, step_s: float, log: Any) -> StepError:
    """doStep returned ``status`` (Error, Fatal or a Discard that is no termination) at step ``k``."""
    return StepError(
        f"{info.model_name}: doStep returned {STATUS_NAMES[status]} at step {k} "
        f"(t={time_s:g} s, h={step_s:g} s); reset() the model to continue, and see the "
        f"FMU log for the cause [{info.path}]",
        step=k,
        time_s=time_s,
        log=log,
    )


def step_refused(
    info: ModelInfo, state: str, failed_status: int, *, k: int, time_s: float, log: Any
) -> StepError:
    """A step asked of a model that cannot step: ``state`` is ``closed``, ``new`` (not initialised),
    ``terminated``, or empty after the failed step of ``failed_status``."""
    reasons = {
        "closed": "the model is closed",
        "new": "the model is not initialised: call initialize() or reset() first",
        "terminated": "the FMU requested termination: reset() before stepping again",
    }
    reason = reasons.get(state) or f"the previous step failed ({STATUS_NAMES[failed_status]}): reset() first"
    return StepError(f"{info.model_name}: cannot step at step {k}: {reason}", step=k, time_s=time_s, log=log)
