"""Stepping model-exchange FMUs: CVode (from FMPy's SUNDIALS binding) plus FMI event handling.

FMPy removed its ME-to-CS wrapper, so this is ours. Between two communication points the
integrator runs until the end point, a state event (root of an event indicator), a time
event announced by the FMU, or a step event from completedIntegratorStep; each event runs the
FMI event iteration and restarts the integrator. Inputs are zero-order held, so the integrator
is also restarted at every communication point where inputs may have jumped.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from fmpy.sundials import CVodeSolver

from bridge.errors import StepError
from bridge.fmu.backend import Backend
from bridge.fmu.events import EventCalls, needs_completed_step


class _HeldInputs:
    """CVode's root function re-applies inputs; ours are set once per sample and held."""

    def apply(
        self, time: float, continuous: bool = True, discrete: bool = True, after_event: bool = False
    ) -> None:
        return None


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)


class MeStepper:
    """Integrates one model-exchange instance; the instance must be in continuous-time mode."""

    def __init__(
        self,
        backend: Backend,
        start_s: float,
        tolerance: float,
        max_step_s: float,
        next_event_s: float | None,
    ) -> None:
        self._backend = backend
        self._fmu: Any = backend.fmu
        info = backend.info
        major = backend.major
        self.events = EventCalls(self._fmu, major)
        self._needs_completed = needs_completed_step(info, major)
        self.next_event_s = next_event_s
        fmu = self._fmu
        self._get_nominals = (
            fmu.getNominalContinuousStates if major == 1 else fmu.getNominalsOfContinuousStates
        )
        self._solver = CVodeSolver(
            nx=info.number_of_states,
            nz=info.number_of_event_indicators,
            get_x=fmu.getContinuousStates,
            set_x=fmu.setContinuousStates,
            get_dx=fmu.getContinuousStateDerivatives if major == 3 else fmu.getDerivatives,
            get_z=fmu.getEventIndicators,
            get_nominals=self._nominals,
            set_time=fmu.setTime,
            input=_HeldInputs(),
            startTime=start_s,
            maxStep=max_step_s,
            relativeTolerance=tolerance,
        )

    @property
    def fmu(self) -> Any:
        """The FMPy object the stepper calls (the same across re-instantiation)."""
        return self._fmu

    def _nominals(self, pointer: Any, n: int) -> None:
        """State nominals scale CVode's absolute tolerance; some exporters report 0 (illegal there)."""
        self._get_nominals(pointer, n)
        nominal = np.ctypeslib.as_array(pointer, (n,))
        bad = ~np.isfinite(nominal) | (nominal <= 0.0)
        if bad.any():
            nominal[bad] = 1.0

    def restart(self, time_s: float) -> None:
        """Re-read states after a reset, a restored snapshot or an input jump."""
        self._solver.reset(time_s)

    def handle_event(self, time_s: float, step: int) -> bool:
        """Event mode, discrete iteration, back to continuous time; True if termination requested."""
        terminate, self.next_event_s = self.events.handle()
        if not terminate:
            self._solver.reset(time_s)
        return terminate

    def advance(self, start_s: float, end_s: float, step: int, *, restart: bool) -> bool:
        """Integrate from ``start_s`` to ``end_s``; returns True if the FMU requested termination."""
        time_s = start_s
        if restart:
            self._solver.reset(time_s)
        while not _close(time_s, end_s) and time_s < end_s:
            target = end_s
            if self.next_event_s is not None and time_s < self.next_event_s < end_s:
                target = self.next_event_s
            try:
                state_event, _, time_s = self._solver.step(time_s, target)
            except Exception as exc:
                raise StepError(
                    f"{self._backend.info.model_name}: the ODE solver failed at t={time_s:g} s "
                    f"(step {step}): {exc}",
                    step=step,
                    time_s=time_s,
                    log=self._backend.log.recent(),
                ) from exc
            self._fmu.setTime(time_s)
            step_event, terminate = self._completed()
            if terminate:
                return True
            time_event = self.next_event_s is not None and _close(time_s, self.next_event_s)
            if (state_event or time_event or step_event) and self.handle_event(time_s, step):
                return True
        return False

    def _completed(self) -> tuple[bool, bool]:
        if not self._needs_completed:
            return False, False
        return self.events.completed_step()
