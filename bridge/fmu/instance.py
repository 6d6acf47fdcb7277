"""``Instance``: one FMU instance's runtime, and the one interface its steppers use.

What stepping an instance needs, apart from how it is set up and reset (``bridge.fmu.model``):
its FMI calls (the backend), its clock (the step index ``k`` in one C ``long long``, ``t = t0 +
k * h``), its step (:meth:`Instance.advance`, model exchange and clocks included), its state
(initialised, terminated, failed, closed) and the errors of a failed or refused step.
:class:`~bridge.fmu.model.Model` is an ``Instance`` that adds settings, variables, initialisation,
resets and saved states; a subclass keeps one object per instance, so the per-step path reads its
fields directly, without a second object in between.

The native steppers of this package (the one-call sample ``bridge.fmu.sample``, the batch
``bridge.fmu.batch``, the system's native master ``bridge.fmu.system_step``) and state-file
starts (``bridge.fmu.start_state``) step an instance through the public members under "the
stepping interface" below, never through its private ones (tests/fmu/test_model_privates.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bridge.errors import ConfigError, FmuError
from bridge.fmu import exchange
from bridge.fmu.abi import DISCARD, WARNING, Clock
from bridge.fmu.backend import Backend
from bridge.fmu.clocks import ClockDriver
from bridge.fmu.description import Interface, ModelInfo
from bridge.fmu.fixed_step import FixedStepper
from bridge.fmu.stepping import function_addresses, step_failed, step_refused


class Instance:
    """One FMU instance's runtime: backend, clock, step and state (built by :class:`Model`)."""

    info: ModelInfo
    interface: Interface
    start_time_s: float
    step_size_s: float
    terminated: bool
    _backend: Backend
    _clock: Clock
    _do_step: Callable[[float, float], int]
    # read by the steppers (the stepping interface below), set only by the instance itself
    initialized: bool  # initialised, or standing in a state set over an instance
    closed: bool  # freed: a new Model is needed
    failed_status: int  # the FMI status of the last failed step (0: none since the last reset)
    _init_failed: bool
    _me: exchange.Integrator | None
    _clocks: ClockDriver | None
    _handles: tuple[Any, dict[str, int]] | None  # (the instance, its addresses)
    _inputs_dirty: bool

    # -- FMI 3.0 clocks ------------------------------------------------------------------------
    @property
    def clock_ticks(self) -> list[tuple[float, str]]:
        """``(time in s, clock name)`` of every clock tick since the start (input clocks as activated,
        output clocks as the FMU reported them; the most recent 100 000), in order."""
        return list(self._clocks.ticks) if self._clocks is not None else []

    def activate_clock(self, name: str) -> None:
        """Tick the triggered input clock ``name`` at the current time (before the next step)."""
        if self._clocks is None:
            raise ConfigError(
                f"{self.info.model_name}: clocks tick only in FMI 3.0 co-simulation with event mode or "
                f"scheduled execution; {name!r} cannot be activated here"
            )
        self._clocks.activate(name)

    # -- the FMU's log and events ------------------------------------------------------------------
    @property
    def log(self) -> list[str]:
        """The FMU's most recent log messages."""
        return list(self._backend.log.messages)

    def write_in_event_mode(self, write: Callable[[], None]) -> None:
        """Model exchange: ``write`` in event mode, then the discrete-state iteration and continuous time.

        FMI 2.0/3.0 accept discrete inputs and tunable parameters only in event mode; FMI 1.0 takes
        them at any time but needs the event iteration afterwards.
        """
        if self._me is None or self.terminated:  # before initialisation every value is accepted
            write()
            return
        terminated = exchange.write_in_event_mode(self._backend, self._me, write)
        self._inputs_dirty = True
        self.terminated = self.terminated or terminated

    # -- the clock ----------------------------------------------------------------------------
    @property
    def step_index(self) -> int:
        """FMU steps ``k`` since the start time (the model's only clock)."""
        return self._clock.value

    @step_index.setter
    def step_index(self, k: int) -> None:
        self._clock.value = k

    @property
    def time_s(self) -> float:
        """Simulation time ``t0 + k * h`` of the current step index ``k``."""
        return self.start_time_s + self._clock.value * self.step_size_s

    # -- stepping -----------------------------------------------------------------------------
    def advance(self, n: int = 1) -> bool:
        """Advance ``n`` FMU steps from the current step index; True if the FMU asked to terminate.

        Raises:
            StepError: the FMU returned Error/Fatal/Discard, or stepping after termination.
        """
        if not self.initialized or self.terminated or self.failed_status:
            self._refuse_step()
        clock = self._clock
        if n == 1 and self._me is None:  # one FMU step per sample: the common hot path
            k = clock.value
            status = self._do_step(self.start_time_s + k * self.step_size_s, self.step_size_s)
            if status > WARNING:
                return self._step_failed(status)
            clock.value = k + 1
            return False
        if self._me is not None:
            return self._advance_me(n)
        k, t0, h, do_step = clock.value, self.start_time_s, self.step_size_s, self._do_step
        for _ in range(n):
            status = do_step(t0 + k * h, h)
            if status > WARNING:
                clock.value = k
                return self._step_failed(status)
            k += 1
        clock.value = k
        return False

    def _advance_me(self, n: int) -> bool:
        assert self._me is not None  # guarded by the caller
        if self._clocks is not None:
            return self._advance_clocked_me(n)
        start = self.time_s
        end = self.start_time_s + (self.step_index + n) * self.step_size_s
        # Inputs are held piecewise constant: restart the integrator only where they may have jumped.
        restart, self._inputs_dirty = self._inputs_dirty, False
        terminated = self._me.advance(start, end, self.step_index, restart=restart)
        self.step_index += n
        self.terminated = terminated
        return terminated

    def _advance_clocked_me(self, n: int) -> bool:
        """Model exchange with clocks: each FMU step integrated between the clocks' ticks."""
        clocks, me = self._clocks, self._me
        assert clocks is not None and me is not None  # guarded by the caller

        def integrate(t0: float, t1: float) -> bool:
            restart, self._inputs_dirty = self._inputs_dirty, False
            return me.advance(t0, t1, self.step_index, restart=restart)

        def after_event(t: float, next_event_s: float | None) -> None:
            me.restart(t)
            me.next_event_s = next_event_s

        clocks.integrate, clocks.after_event = integrate, after_event
        for _ in range(n):
            status = clocks.step(self.time_s, self.step_size_s)
            if status > WARNING:
                return self._step_failed(status)
            self.step_index += 1
        return False

    def _step_failed(self, status: int) -> bool:
        stopped = self._clocks.terminated if self._clocks is not None else False
        if status == DISCARD and (stopped or self._backend.terminated_after_discard()):
            self.step_index += 1
            self.terminated = True
            return True
        self.failed_status = status
        log = self._backend.log.recent()
        raise step_failed(
            self.info, status, k=self.step_index, time_s=self.time_s, step_s=self.step_size_s, log=log
        )

    def _refuse_step(self) -> None:
        state = "closed" if self.closed else "new" if not self.initialized else ""
        state = state or ("terminated" if self.terminated else "")
        log = self._backend.log.recent()
        raise step_refused(
            self.info, state, self.failed_status, k=self.step_index, time_s=self.time_s, log=log
        )

    # -- the stepping interface -------------------------------------------------------------------
    # What the steppers of this package (the native sample, the batch, the system's native master,
    # state-file starts) use to step this instance and account for what they did; nothing else
    # of the model is theirs to touch.
    @property
    def backend(self) -> Backend:
        """The FMI calls of this instance (``bridge.fmu`` only: FMI names stop there)."""
        return self._backend

    @property
    def clock(self) -> Clock:
        """The C ``long long`` holding the step index ``k``, which native steppers advance in place."""
        return self._clock

    def attach_clock(self, clock: Clock) -> None:
        """Keep ``k`` in ``clock`` from now on (a cell of a batch's array), carrying its value over."""
        clock.value = self._clock.value
        self._clock = clock

    @property
    def steppable(self) -> bool:
        """True if :meth:`advance` would step now (open, initialised, not terminated, not failed)."""
        return self.initialized and not self.terminated and not self.failed_status and not self.closed

    @property
    def clocked(self) -> bool:
        """Whether FMI 3.0 clocks tick in this instance (in Python: :mod:`bridge.fmu.clocks`)."""
        return self._clocks is not None

    def native_handles(self) -> dict[str, int]:
        """Addresses for a native stepper that calls this instance's FMI functions directly.

        Keys: ``component`` (the instance), ``major`` (FMI version), ``set_real``, ``get_real``,
        ``do_step`` and ``bool_status`` (the Float64 set/get, doStep and, for FMI 2.0,
        fmi2GetBooleanStatus; 0 where absent), ``get_state``, ``set_state``, ``free_state`` (the
        FMU state functions; 0 where absent). Valid while the model is open and initialised; the
        same dict while the instance is the same (a reset by restore or fmi reset keeps it).
        In model exchange (fixed-step solvers only) :attr:`fixed_stepper` integrates.
        """
        b, cached = self._backend, self._handles
        if cached is not None and cached[0] is b.component:  # the same instance: the same addresses
            return cached[1]
        if self._clocks is not None:
            raise FmuError(
                f"{self.info.model_name}: its clocks tick in Python (bridge.fmu.clocks), not natively"
            )
        if b.major < 2 or not b.component or (self.interface == "me" and self.fixed_stepper is None):
            raise FmuError(
                f"{self.info.model_name}: native stepping needs an initialised FMI 2.0/3.0 instance "
                f"(co-simulation, or model exchange with solver 'rk4' or 'euler')"
            )
        handles = function_addresses(b)
        self._handles = (b.component, handles)
        return handles

    @property
    def fixed_stepper(self) -> FixedStepper | None:
        """The native fixed-step integrator of a model-exchange instance (solver 'rk4' or
        'euler', once initialised); None otherwise."""
        return self._me if isinstance(self._me, FixedStepper) else None

    def me_finish(self, code: int, n: int) -> bool:
        """Finish a sample of ``n`` FMU steps from the current step index that a native batch
        loop began with :attr:`fixed_stepper` and stopped with ``code`` (an event, termination or
        a failure); the model then stands after the sample. True if the FMU asked to terminate.

        Raises:
            StepError: as :meth:`advance` does.
        """
        stepper = self.fixed_stepper
        if stepper is None:
            raise FmuError(f"{self.info.model_name}: no fixed-step integrator to finish the sample with")
        k, t0, h = self.step_index, self.start_time_s, self.step_size_s
        terminated = stepper.finish(code, t0 + k * h, t0 + (k + n) * h, k)
        self.step_index, self.terminated = k + n, terminated
        return terminated

    def native_step_failed(self, status: int) -> bool:
        """Account for a native doStep at the current step index that returned ``status``
        (> Warning): True if the FMU asked to terminate, else :class:`StepError`."""
        return self._step_failed(status)

    def inputs_written(self) -> None:
        """Inputs were written through a signal group: model exchange restarts its integrator."""
        self._inputs_dirty = True
