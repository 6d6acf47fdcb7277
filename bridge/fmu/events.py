"""The FMI calls around model-exchange events, one shape for FMI 1.0, 2.0 and 3.0.

FMI 2.0 and 3.0 have modes: discrete inputs and tunable parameters change only in event mode,
followed by the discrete-state iteration and the return to continuous-time mode. FMI 1.0 has no
modes: values are set at any time and ``fmiEventUpdate`` is iterated until it converges.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bridge.fmu.description import ModelInfo


class EventCalls:
    """Event-mode entry, discrete-state iteration and return to continuous time for one instance."""

    def __init__(self, fmu: Any, major: int) -> None:
        self._fmu = fmu
        self.major = major

    def enter_event_mode(self) -> None:
        if self.major >= 2:
            self._fmu.enterEventMode()

    def enter_continuous_time_mode(self) -> None:
        if self.major >= 2:
            self._fmu.enterContinuousTimeMode()

    def iterate(self) -> tuple[bool, float | None]:
        """Run the discrete-state iteration: (termination requested, next time event or None)."""
        if self.major == 1:
            return fmi1_iterate(self._fmu, None)
        update = self._fmu.updateDiscreteStates if self.major == 3 else self._fmu.newDiscreteStates
        needed, terminate, defined, next_time = True, False, False, 0.0
        while needed and not terminate:
            needed, terminate, _, _, defined, next_time = update()
        return bool(terminate), (float(next_time) if defined else None)

    def handle(self) -> tuple[bool, float | None]:
        """An event during integration: event mode, the discrete-state iteration, and back to
        continuous time unless the FMU asks to terminate; returns what :meth:`iterate` does."""
        self.enter_event_mode()
        terminate, next_time = self.iterate()
        if not terminate:
            self.enter_continuous_time_mode()
        return terminate, next_time

    def completed_step(self) -> tuple[bool, bool]:
        """completedIntegratorStep: (event mode needed, termination requested)."""
        result = self._fmu.completedIntegratorStep()
        if self.major == 1:
            return bool(result), False
        return bool(result[0]), bool(result[1])


def needs_completed_step(info: ModelInfo, major: int) -> bool:
    """Whether completedIntegratorStep must follow each integrator step (FMI 2.0 declares it;
    FMI 1.0 and 3.0 always call it)."""
    me = info.raw.modelExchange if info.raw is not None else None
    return bool(me is not None and (major != 2 or me.needsCompletedIntegratorStep))


Fmi1EventInfo = tuple[bool, bool, bool, bool, bool, float]


def fmi1_iterate(fmu: Any, first: Fmi1EventInfo | None) -> tuple[bool, float | None]:
    """FMI 1.0: call fmiEventUpdate until the iteration converges (``first``: fmiInitialize's result)."""
    info = first if first is not None else fmu.eventUpdate()
    while not info[0] and not info[3]:
        info = fmu.eventUpdate()
    _, _, _, terminate, upcoming, next_time = info
    return bool(terminate), (float(next_time) if upcoming else None)
