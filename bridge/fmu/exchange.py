"""Model exchange of one :class:`~bridge.fmu.model.Model` instance, around its integrator.

What the model calls between initialisation and its steps when the FMU is model exchange: the
integrator it steps with (CVode, or a native fixed-step one: ``bridge.fmu.solver``,
``bridge.fmu.fixed_step``), the initial event iteration that leaves initialisation, values set in
event mode, and the continuous states and derivatives read and set directly.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from bridge.errors import FmuError, VariableError
from bridge.fmu.backend import Backend
from bridge.fmu.description import ModelInfo
from bridge.fmu.events import EventCalls
from bridge.fmu.fixed_step import FixedStepper
from bridge.fmu.solver import MeStepper
from bridge.fmu.spec import Solver

Integrator = MeStepper | FixedStepper


def integrator(
    backend: Backend,
    solver: Solver,
    substeps: int,
    grid: tuple[float, float],
    tolerances: tuple[float | None, float | None],
    *,
    next_event_s: float | None,
) -> Integrator:
    """The integrator of ``solver`` on the time grid ``(t0, h)``. ``tolerances``: the one asked for
    (None: none) and the FMU's default; CVode takes the first, else the default but at most 1e-6."""
    t0, h = grid
    if solver != "cvode":
        return FixedStepper(backend, solver, substeps, h, next_event_s)
    # An exporter's default tolerance is tuned for its own solver; restarting CVode at every
    # input change needs a tighter one, so 1e-6 unless the caller asks for another.
    requested, default = tolerances
    tolerance = requested or min(default or 1e-6, 1e-6)
    return MeStepper(backend, t0, tolerance, h, next_event_s)


def leave_initialization(backend: Backend, model_name: str) -> float | None:
    """The initial event iteration, then continuous-time mode; the next time event (None: none).
    FMI 2.0 and 3.0 both leave initialisation in event mode; FMI 1.0's fmiInitialize has iterated
    already (the backend finished it)."""
    events = EventCalls(backend.fmu, backend.major)
    if backend.major == 1:
        terminate, next_event = getattr(backend, "initial_events", (False, None))
    else:
        terminate, next_event = backend.call("the initial event iteration", events.iterate)
    if terminate:
        raise FmuError(f"{model_name}: the FMU requested termination during initialisation")
    backend.call("enterContinuousTimeMode", events.enter_continuous_time_mode)
    return next_event


def write_in_event_mode(backend: Backend, me: Integrator, write: Callable[[], None]) -> bool:
    """``write`` in event mode, then the discrete-state iteration and continuous time; True where
    the FMU asked to terminate (it then stays in event mode)."""
    events, call = me.events, backend.call
    call("enterEventMode", events.enter_event_mode)
    write()
    terminate, me.next_event_s = call("the event iteration", events.iterate)
    if terminate:
        return True
    call("enterContinuousTimeMode", events.enter_continuous_time_mode)
    return False


def _call(backend: Backend, info: ModelInfo, ready: bool, name: str, array: npt.NDArray[np.float64]) -> None:
    if not ready:
        raise FmuError(
            f"{info.model_name}: {name} needs an initialised model-exchange instance "
            f"(open the Model with interface='me' and initialize() it)"
        )
    fmu = backend.fmu
    pointer = array.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
    backend.call(name, lambda: getattr(fmu, name)(pointer, len(array)))


def continuous_states(backend: Backend, info: ModelInfo, ready: bool) -> npt.NDArray[np.float64]:
    """The continuous states now, in the FMU's order (``ready``: an initialised ME instance)."""
    x = np.zeros(info.number_of_states)
    _call(backend, info, ready, "getContinuousStates", x)
    return x


def set_continuous_states(backend: Backend, info: ModelInfo, ready: bool, x: npt.ArrayLike) -> None:
    """Set the continuous states ``x`` (in continuous-time mode)."""
    values = np.ascontiguousarray(x, dtype=np.float64)
    if values.shape != (info.number_of_states,):
        raise VariableError(
            f"{info.model_name}: {info.number_of_states} continuous states expected, "
            f"got an array of shape {values.shape}"
        )
    _call(backend, info, ready, "setContinuousStates", values)


def derivatives(backend: Backend, info: ModelInfo, ready: bool) -> npt.NDArray[np.float64]:
    """The state derivatives at the current states and inputs."""
    dx = np.zeros(info.number_of_states)
    _call(
        backend, info, ready, "getContinuousStateDerivatives" if backend.major == 3 else "getDerivatives", dx
    )
    return dx
