"""Stepping model-exchange FMUs with a fixed-step explicit method (RK4 or forward Euler) in C.

The integration loop (``fixed_step.c``) calls the FMU's own functions between events, so no
right-hand side is evaluated in Python: a sample without events is one native call. It stops at
state events (a sign change of an event indicator, located by bisection within a substep), at
time events announced by the FMU and at step events from completedIntegratorStep; the event
iteration then runs here with the same FMI calls as for CVode (``bridge.fmu.solver``), and the
loop resumes from the event. Inputs are zero-order held; states are read from the instance at
every call, so resets, restored snapshots and input changes need no restart.

The grid is ``t0 + k h + j h / substeps`` (``j = 1 .. substeps`` per FMU step ``h``); after an
event inside a substep, the rest of that substep is integrated up to the next grid point.
"""

from __future__ import annotations

import ctypes
import math
from typing import Final

import numpy as np

from bridge.errors import ConfigError, StepError
from bridge.fmu import native
from bridge.fmu.abi import END, FAILED, STATUS_NAMES, TERMINATE, FixedCall, FixedSpec
from bridge.fmu.backend import Backend
from bridge.fmu.events import EventCalls, needs_completed_step

METHODS: Final = {"euler": 0, "rk4": 1}
MAX_EVENTS: Final = 100_000  # per sample: more means the model chatters
_FUNCTIONS: Final = {
    2: ("SetTime", "SetContinuousStates", "GetContinuousStates", "GetDerivatives",
        "GetEventIndicators", "CompletedIntegratorStep"),
    3: ("SetTime", "SetContinuousStates", "GetContinuousStates", "GetContinuousStateDerivatives",
        "GetEventIndicators", "CompletedIntegratorStep"),
}  # fmt: skip


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)


class FixedStepper:
    """Integrates one FMI 2.0/3.0 model-exchange instance; it must be in continuous-time mode.

    Args:
        backend: the instance's backend.
        method: ``"rk4"`` or ``"euler"``.
        substeps: integration steps per FMU step ``step_size_s``.
        next_event_s: the time event the FMU announced at initialisation, or None.
    """

    def __init__(
        self, backend: Backend, method: str, substeps: int, step_size_s: float, next_event_s: float | None
    ) -> None:
        if backend.major not in _FUNCTIONS or method not in METHODS or substeps < 1:
            raise ConfigError(
                f"{backend.info.model_name}: fixed-step integration needs FMI 2.0/3.0 model exchange, "
                f"method {tuple(METHODS)} and substeps >= 1; got FMI {backend.info.fmi_version}, "
                f"{method!r}, {substeps}: use solver 'cvode' for FMI 1.0"
            )
        self._backend, self.fmu = backend, backend.fmu
        self.events = EventCalls(self.fmu, backend.major)
        self._call = FixedCall()
        self.next_event_s = next_event_s
        self._h, self._substeps = step_size_s, substeps
        info = backend.info
        self._work = np.zeros(7 * info.number_of_states + 3 * info.number_of_event_indicators)
        self._spec = FixedSpec(
            backend.major, METHODS[method], info.number_of_states, info.number_of_event_indicators,
            needs_completed_step(info, backend.major), *self._addresses(), self._work.ctypes.data,
        )  # fmt: skip
        self._run = native.load("fixed_step").fixed_step_advance
        self._run.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        self._run.restype = ctypes.c_int
        self._args = (ctypes.addressof(self._spec), ctypes.addressof(self._call))
        self.restart(0.0)

    def _addresses(self) -> list[int]:
        prefix = f"fmi{self._backend.major}"
        found = []
        for name in _FUNCTIONS[self._backend.major]:
            fn = self._backend.functions.get(prefix + name)
            address = ctypes.cast(fn, ctypes.c_void_p).value if fn is not None else None
            if not address:
                raise ConfigError(
                    f"{self._backend.info.model_name}: the FMU does not export {prefix}{name}, which "
                    f"fixed-step integration calls; use solver 'cvode'"
                )
            found.append(address)
        return found

    @property
    def next_event_s(self) -> float | None:
        """The time event the FMU announced (None: none); kept in the call for batches too."""
        value = self._call.announced
        return None if math.isnan(value) else value

    @next_event_s.setter
    def next_event_s(self, value: float | None) -> None:
        self._call.announced = math.nan if value is None else value

    @property
    def substeps(self) -> int:
        return self._substeps

    def addresses(self) -> tuple[int, int]:
        """The addresses of this instance's C spec and call (for ``fixed_step_batch``)."""
        return ctypes.addressof(self._spec), ctypes.addressof(self._call)

    def restart(self, time_s: float) -> None:
        """Point the loop at the current instance (after instantiation, reset or restore)."""
        self._call.component = ctypes.cast(self._backend.component, ctypes.c_void_p).value

    def handle_event(self, time_s: float, step: int) -> bool:
        """Event mode, discrete iteration, back to continuous time; True if termination requested."""
        terminate, self.next_event_s = self.events.handle()
        return terminate

    def advance(self, start_s: float, end_s: float, step: int, *, restart: bool = False) -> bool:
        """Integrate from ``start_s`` to ``end_s``; returns True if the FMU requested termination."""
        call = self._call
        call.time = call.origin = start_s
        call.end = end_s
        call.total = total = max(1, round((end_s - start_s) / self._h)) * self._substeps
        call.substep = (end_s - start_s) / total
        return self.finish(None, start_s, end_s, step)

    def finish(self, code: int | None, start_s: float, end_s: float, step: int) -> bool:
        """Go on with the call set up for ``start_s`` .. ``end_s`` from where the loop stopped with
        ``code`` (None: it has not run yet) to its end; True if the FMU requested termination."""
        call, run, args = self._call, self._run, self._args
        for _ in range(MAX_EVENTS):
            if code is None:
                event = self.next_event_s
                time_s = call.time
                due = event is not None and time_s < event and not _close(time_s, event)
                call.next_event = event if due else math.nan
                code = run(*args)
            if code == END:
                return False
            if code == TERMINATE:
                return True
            if code >= FAILED:
                raise self._failure(code, step, call.time)
            if self.handle_event(call.time, step):
                return True
            code = None
        raise StepError(
            f"{self._backend.info.model_name}: more than {MAX_EVENTS} events between t={start_s:g} s and "
            f"t={end_s:g} s (step {step}, now t={call.time:g} s): the model chatters (events that keep "
            f"re-triggering); check its event indicators, or sample more often",
            step=step,
            time_s=call.time,
            log=self._backend.log.recent(),
        )

    def _failure(self, code: int, step: int, time_s: float) -> StepError:
        b = self._backend
        function, status = divmod(code - FAILED, 16)
        name = f"fmi{b.major}{_FUNCTIONS[b.major][function]}"
        return StepError(
            f"{b.info.model_name}: {name} returned {STATUS_NAMES[min(status, 5)]} at t={time_s:g} s "
            f"(step {step}) during fixed-step integration; reset() the model to continue, and see the "
            f"FMU log for the cause",
            step=step,
            time_s=time_s,
            log=b.log.recent(),
        )
