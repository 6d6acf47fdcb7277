"""FMI 3.0 clocks that tick: co-simulation in event mode and scheduled execution.

The importer owns the time-based input clocks (FMI 3.0 §2.2.9): it asks the FMU for their intervals
and shifts (or takes them from modelDescription.xml) and activates each at its ticks.

- ``constant``: ``t_i = t_start + shift + i * interval`` from the XML.
- ``fixed``: the XML's ``intervalDecimal`` (or the one set with ``fmi3SetIntervalDecimal`` in
  initialization mode); without one, the FMU calculates interval and shift, read in initialization mode.
- ``tunable``: as fixed; a new interval reported in event mode (``fmi3IntervalChanged``) starts from
  that event.
- ``changing``: the first tick ``t_start + T_0``; after each of its ticks the FMU reports the next interval.
- ``countdown``: the FMU reports an interval relative to the current event whenever it knows one
  (``fmi3IntervalNotYetKnown`` otherwise), asked in initialization mode and at every event.
- ``triggered`` input clocks tick when the experiment's schedule or the agent says.

One FMU step ``[t, t + h]`` is split at every tick inside it: ``fmi3DoStep`` to the tick, event mode
there (``fmi3SetClock``, ``fmi3UpdateDiscreteStates`` until done, output clocks and new intervals
read), ``fmi3EnterStepMode``, and on to the next tick or ``t + h``. A tick on ``t + h`` is handled at
the end of the step, so the values read after the step include it. Ticks at the same time are
activated together; in scheduled execution their model partitions run in priority order
(``fmi3ActivateModelPartition``), with the FMU's ``fmi3ClockUpdateCallback`` answered by reading
the output clocks and the intervals it may have changed.
"""

from __future__ import annotations

import ctypes
import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from fmpy import fmi3

from bridge.errors import ConfigError, FmuError
from bridge.fmu.abi import DISCARD, ERROR, OK, WARNING
from bridge.fmu.clock_rules import _check_intervals, _check_schedule, check_settings, clock_driver_needed
from bridge.fmu.description import ModelInfo, Variable

NOT_YET_KNOWN, UNCHANGED, CHANGED = 0, 1, 2
TIME_BASED = ("constant", "fixed", "tunable", "changing", "countdown")
_MAX_ITERATIONS = 1000  # fmi3UpdateDiscreteStates calls at one event before giving up
MAX_TICKS_KEPT = 100_000  # the tick log keeps the most recent ones


@dataclass(frozen=True)
class Timing:
    """Where one input clock ticks next: ``base + index * interval`` while periodic, else ``next_s``."""

    interval_s: float | None = None
    base_s: float | None = None
    index: int = 0
    next_s: float | None = None

    @property
    def due_s(self) -> float | None:
        if self.base_s is not None and self.interval_s is not None:
            return self.base_s + self.index * self.interval_s
        return self.next_s


class ClockDriver:
    """The clocks of one FMI 3.0 instance: their schedule, the events at their ticks and a tick log.

    ``step(t, h)`` is the instance's step function (as ``doStep`` is for a co-simulation without
    clocks); ``configure`` runs in initialization mode, ``start`` right after it.
    """

    def __init__(
        self,
        backend: Any,
        info: ModelInfo,
        interface: str,
        *,
        intervals: Mapping[str, float] | None = None,
        schedule: Mapping[str, Sequence[float]] | None = None,
    ) -> None:
        self._backend, self.info, self.scheduled = backend, info, interface == "se"
        self.me = interface == "me"
        # model exchange: the model integrates [t0, t1] (True: termination) and restarts its
        # integrator after an event at t with the FMU's next time event
        self.integrate: Callable[[float, float], bool] | None = None
        self.after_event: Callable[[float, float | None], None] | None = None
        self.inputs = sorted((v for v in info.clocks if v.causality == "input"), key=_priority)
        self.outputs = [v for v in info.clocks if v.causality == "output"]
        self._by_name = {v.name: v for v in self.inputs}
        self.triggered = {
            n for n, v in self._by_name.items() if v.clock and v.clock.interval_variability == "triggered"
        }
        self._asked = [
            (v, v.clock.interval_variability)
            for v in self.inputs
            if v.clock is not None
            and (
                v.clock.interval_variability in ("countdown", "changing")
                or (v.clock.interval_variability == "tunable" and v.clock.interval_s is None)
            )
        ]
        self._vr = {v.name: _vrs([v]) for v in info.clocks}  # one value reference per call
        self._set_vrs: dict[tuple[str, ...], tuple[Any, Any]] = {}  # fmi3SetClock's arguments
        self._interval_buf = ((fmi3.fmi3Float64 * 1)(), (fmi3.fmi3IntervalQualifier * 1)())
        self._output_buf = (_vrs(self.outputs), (fmi3.fmi3Clock * len(self.outputs))())
        self._intervals = _check_intervals(info, self._by_name, intervals or {})
        self._schedule = _check_schedule(info, self._by_name, schedule or {})
        self.timing: dict[str, Timing] = {}
        self._initial: dict[str, Timing] = {}
        self._pending: set[str] = set()
        self._schedule_pos: dict[str, int] = {}
        self.ticks: deque[tuple[float, str]] = deque(maxlen=MAX_TICKS_KEPT)
        self._logged = 0  # ticks logged since the start (also those the deque no longer keeps)
        self.terminated = False
        self._time = 0.0
        self._flags = [fmi3.fmi3Boolean() for _ in range(5)]
        self._next_event = fmi3.fmi3Float64()
        self._in_event = False
        self._activation_time = 0.0
        self._callback_error: Exception | None = None
        self._fired: list[str] = []
        # clocked variables (numeric, not inputs) by clock; their values read at the ticks
        self._clocked: dict[str, list[Variable]] = {}
        for var in info.variables.values():
            if var.clocks and var.is_numeric and var.causality != "input":
                for clock in var.clocks:
                    self._clocked.setdefault(clock, []).append(var)
        self.held: dict[str, list[Any]] = {}
        # the model's reader of a list of numeric variables (a SignalGroup over their elements)
        self.read_values: Callable[[list[Variable]], Any] | None = None
        self._readers: dict[tuple[str, ...], tuple[list[Variable], Any]] = {}
        self._fmu_event_s: float | None = None  # the FMU's next time event (co-simulation)
        self._initial_event_s: float | None = None
        self._start_ticks: list[tuple[float, str]] = []
        self._start_positions: dict[str, int] = {}
        self._initial_held: dict[str, list[Any]] = {}

    # -- set-up ----------------------------------------------------------------------------------
    def configure(self, start_s: float) -> None:
        """In initialization mode: set the intervals the importer chooses, read the others."""
        fmu, component = self._backend.fmu, self._backend.component
        self._time = start_s
        if self._intervals:
            variables = [self._by_name[name] for name in self._intervals]
            vrs, n = _vrs(variables), len(variables)
            values = (fmi3.fmi3Float64 * n)(*self._intervals.values())
            self._call(
                "fmi3SetIntervalDecimal", lambda: fmu.fmi3SetIntervalDecimal(component, vrs, n, values)
            )
        timing = {}
        for var in self.inputs:
            clock = var.clock
            assert clock is not None  # inputs are clocks
            kind = clock.interval_variability
            if kind not in TIME_BASED:
                continue
            if kind in ("changing", "countdown"):
                interval, qualifier = self._interval(var)
                due = start_s + interval if qualifier != NOT_YET_KNOWN else None
                timing[var.name] = Timing(next_s=due)
                continue
            if clock.interval_s is not None:  # given by the XML (fixed/tunable: or set by the importer)
                interval = self._intervals.get(var.name, clock.interval_s)
                shift = clock.shift_s or 0.0
            else:
                interval, _ = self._interval(var)
                shift = self._shift(var)
            if not (math.isfinite(interval) and interval > 0):
                raise FmuError(
                    f"{self.info.model_name}: clock {var.name} has interval {interval!r}; expected > 0"
                )
            timing[var.name] = Timing(interval_s=interval, base_s=start_s + shift)
        self.timing = timing
        self.held.clear()
        for clock_name in self._clocked:  # clocked variables may be read in initialization mode
            try:
                self._hold([clock_name])
            except FmuError:  # not initialised by this FMU: held from its clock's first tick
                continue

    def start(self, start_s: float) -> None:
        """Right after initialization: the FMU is in event mode (co-simulation) or clock activation
        mode (scheduled execution); the clocks due at the start tick now."""
        self._time, self.terminated, self._fmu_event_s = start_s, False, None
        self._pending.clear()
        self._schedule_pos = {name: 0 for name in self._schedule}
        self.ticks.clear()
        if self.scheduled:
            self._tick(start_s, self._due(start_s))
        else:
            self._in_event = True
            self._event(start_s, self._due(start_s), leave=not self.me)
        if self.me:  # left by the model's own start, right after this, which takes the next time event
            self._in_event, self._fmu_event_s = False, None
        self._start_ticks = list(self.ticks)
        self._logged = len(self._start_ticks)
        self._initial, self._initial_event_s = dict(self.timing), self._fmu_event_s
        self._initial_held = dict(self.held)
        self._start_positions = dict(self._schedule_pos)

    def rewind(self, start_s: float) -> None:
        """After the instance was set back to the state saved right after :meth:`start`."""
        self.timing, self._fmu_event_s = dict(self._initial), self._initial_event_s
        self.held = dict(self._initial_held)
        self._time, self.terminated, self._in_event = start_s, False, False
        self._pending.clear()
        self._schedule_pos = dict(self._start_positions)
        self.ticks.clear()
        self.ticks.extend(self._start_ticks)  # the start's ticks are in the saved state already
        self._logged = len(self._start_ticks)

    def save(self) -> tuple[Any, ...]:
        """What :meth:`load` needs to continue from now (for a saved model state)."""
        positions, pending, held = dict(self._schedule_pos), set(self._pending), dict(self.held)
        timing, event_s = dict(self.timing), self._fmu_event_s
        return timing, self._time, positions, pending, self.terminated, event_s, held, self._logged

    def load(self, saved: tuple[Any, ...]) -> None:
        """Continue from :meth:`save`'s point. The tick log drops the ticks logged after it (a
        rollback, e.g. a system's fixed-point iteration, does not list a tick twice); a state saved
        later than the log's end cannot give back the ticks between, and the log goes on without them."""
        timing, self._time, positions, pending, self.terminated, self._fmu_event_s, held, logged = saved
        for _ in range(min(max(self._logged - logged, 0), len(self.ticks))):
            self.ticks.pop()
        self._logged = logged
        self.timing, self._schedule_pos, self._pending = dict(timing), dict(positions), set(pending)
        self.held = dict(held)
        self._in_event = False

    def write_in_event_mode(self, write: Callable[[], None]) -> None:
        """Write tunable parameters or discrete inputs where the FMU takes them: in event mode
        (co-simulation; then the discrete states are updated) or now (scheduled execution); a
        tunable clock's new interval counts from now."""
        t = self._time
        if self.scheduled:
            write()
        else:
            fmu, component = self._backend.fmu, self._backend.component
            self._call("fmi3EnterEventMode", lambda: fmu.fmi3EnterEventMode(component))
            self._in_event = True
            write()
            self._update_discrete_states()
        self._read_intervals(t, activated=set())
        if self.scheduled or self.terminated:
            return
        if self.me:
            self._call("fmi3EnterContinuousTimeMode", lambda: fmu.fmi3EnterContinuousTimeMode(component))
            self._in_event = False
            next_event, self._fmu_event_s = self._fmu_event_s, None
            if self.after_event is not None:
                self.after_event(t, next_event)
            return
        self._call("fmi3EnterStepMode", lambda: fmu.fmi3EnterStepMode(component))
        self._in_event = False

    # -- activation from outside ------------------------------------------------------------------
    def activate(self, name: str) -> None:
        """Tick the triggered input clock ``name`` at the current time, before the next step."""
        var = self._by_name.get(name)
        if var is None or var.clock is None or var.clock.interval_variability != "triggered":
            triggered = [
                v.name for v in self.inputs if v.clock and v.clock.interval_variability == "triggered"
            ]
            raise ConfigError(
                f"{self.info.model_name}: {name!r} is not a triggered input clock; the agent and the "
                f"schedule can activate {triggered or 'none (this FMU has none)'}"
            )
        self._pending.add(name)

    # -- stepping -----------------------------------------------------------------------------
    def step(self, t: float, h: float) -> int:
        """One FMU step ``[t, t + h]`` split at the ticks inside it; returns an FMI status (DISCARD
        when the FMU asked to terminate)."""
        end = t + h
        tolerance = 1e-9 * h
        now = self._time = t
        if self._pending or self._scheduled_due(now, tolerance):
            self._tick(now, self._due(now, tolerance))
        while not self.terminated:
            due = self._next_due()
            if due is None or due > end + tolerance:
                break
            tick = end if due >= end - tolerance else max(due, now)
            if tick > now and not self.scheduled:
                status = self._do_step(now, tick - now)
                if status > WARNING:
                    return status
            now = self._time = tick
            self._tick(tick, self._due(tick, tolerance))
        if self.terminated:
            return DISCARD
        if end > now and not self.scheduled:
            status = self._do_step(now, end - now)
            if status > WARNING:
                return status
        self._time = end
        return DISCARD if self.terminated else OK

    def _do_step(self, t: float, h: float) -> int:
        """``fmi3DoStep`` over ``[t, t + h]``; an event the FMU asks for at its end is handled there.
        Model exchange: the model's integrator over ``[t, t + h]``."""
        if self.integrate is not None:
            if self.integrate(t, t + h):
                self.terminated = True
                return DISCARD
            return OK
        status: int = self._backend.do_step(t, h)
        if status <= WARNING and self._backend.event_handling_needed():
            self._time = t + h
            self._event(t + h, [])
        return status

    def _tick(self, t: float, names: list[str]) -> None:
        fmu_event = self._fmu_event_s is not None and self._fmu_event_s <= t + 1e-12 * max(1.0, abs(t))
        if not names and not fmu_event:
            return
        if self.scheduled:
            self._activate(t, names)
        else:
            self._event(t, names)

    # -- which clocks are due -------------------------------------------------------------------
    def _next_due(self) -> float | None:
        """The earliest tick ahead: a time-based clock's, the schedule's or the FMU's next time event."""
        times = [d for d in (timing.due_s for timing in self.timing.values()) if d is not None]
        if self._fmu_event_s is not None:
            times.append(self._fmu_event_s)
        for name, times_s in self._schedule.items():
            position = self._schedule_pos.get(name, 0)
            if position < len(times_s):
                times.append(times_s[position])
        return min(times) if times else None

    def _scheduled_due(self, t: float, tolerance: float) -> bool:
        due = self._next_due()
        return due is not None and due <= t + tolerance

    def _due(self, t: float, tolerance: float = 0.0) -> list[str]:
        tolerance = max(tolerance, 1e-12 * max(1.0, abs(t)))
        names = [
            name
            for name, timing in self.timing.items()
            if (d := timing.due_s) is not None and d <= t + tolerance
        ]
        for name, times_s in self._schedule.items():
            position = self._schedule_pos.get(name, 0)
            while position < len(times_s) and times_s[position] <= t + tolerance:
                position += 1
                if name not in names:
                    names.append(name)
            self._schedule_pos[name] = position
        names += [name for name in self._pending if name not in names]
        self._pending.clear()
        order = {v.name: i for i, v in enumerate(self.inputs)}
        return sorted(names, key=order.__getitem__)

    # -- co-simulation: event mode ----------------------------------------------------------------
    def _event(self, t: float, names: list[str], *, leave: bool = True) -> None:
        fmu, component = self._backend.fmu, self._backend.component
        if not self._in_event:
            self._call("fmi3EnterEventMode", lambda: fmu.fmi3EnterEventMode(component))
            self._in_event = True
        if names:
            key = tuple(names)
            arguments = self._set_vrs.get(key)
            if arguments is None:
                variables = [self._by_name[n] for n in names]
                arguments = _vrs(variables), (fmi3.fmi3Clock * len(names))(*([True] * len(names)))
                self._set_vrs[key] = arguments
            vrs, values = arguments
            self._call("fmi3SetClock", lambda: fmu.fmi3SetClock(component, vrs, len(names), values))
        self._update_discrete_states()
        self._log(t, names)
        self._advance(names)
        fired = self._read_outputs(t)
        self._hold([*names, *fired])
        self._read_intervals(t, activated=set(names))
        if self.terminated or not leave:
            return
        if self.me:
            self._call("fmi3EnterContinuousTimeMode", lambda: fmu.fmi3EnterContinuousTimeMode(component))
            self._in_event = False
            next_event, self._fmu_event_s = self._fmu_event_s, None  # the model's integrator has it
            if self.after_event is not None:
                self.after_event(t, next_event)
            return
        self._call("fmi3EnterStepMode", lambda: fmu.fmi3EnterStepMode(component))
        self._in_event = False

    def _update_discrete_states(self) -> None:
        fmu, component = self._backend.fmu, self._backend.component
        need, terminate, defined = self._flags[0], self._flags[1], self._flags[4]
        refs = [ctypes.byref(f) for f in self._flags] + [ctypes.byref(self._next_event)]
        for _ in range(_MAX_ITERATIONS):
            self._call("fmi3UpdateDiscreteStates", lambda: fmu.fmi3UpdateDiscreteStates(component, *refs))
            if terminate.value:
                self.terminated = True
                return
            if not need.value:  # the FMU's own next time event, if it has one
                later = defined.value and self._next_event.value > self._time  # as FMI 3.0 requires
                self._fmu_event_s = float(self._next_event.value) if later else None
                return
        raise FmuError(
            f"{self.info.model_name}: fmi3UpdateDiscreteStates still needs updates after {_MAX_ITERATIONS} "
            f"calls at t={self._time:g} s: the FMU's event iteration does not converge"
        )

    # -- scheduled execution ------------------------------------------------------------------------
    def _activate(self, t: float, names: list[str]) -> None:
        fmu, component = self._backend.fmu, self._backend.component
        for name in names:  # in priority order
            vr = self._by_name[name].value_reference
            self._activation_time = t
            self._advance([name])  # before: the FMU's clock update callback may schedule it anew
            self._log(t, [name])
            self._fired = []
            self._call(
                f"fmi3ActivateModelPartition({name})",
                lambda vr=vr: fmu.fmi3ActivateModelPartition(component, vr, t),  # type: ignore[misc]
            )
            error, self._callback_error = self._callback_error, None
            if error is not None:
                raise error
            self._hold([name, *self._fired])

    def clock_update(self) -> None:
        """The FMU's ``fmi3ClockUpdateCallback`` (scheduled execution): read the output clocks and
        the intervals it may have changed, now, in clock update mode."""
        t = self._activation_time
        try:
            self._fired += self._read_outputs(t)
            self._read_intervals(t, activated=set(self._by_name))
        except Exception as exc:  # a callback cannot raise into the FMU: raised after the activation
            self._callback_error = exc

    # -- after a tick ---------------------------------------------------------------------------------
    def _advance(self, names: list[str]) -> None:
        for name in names:
            timing = self.timing.get(name)
            if timing is None:
                continue
            if timing.base_s is not None:  # periodic: the next multiple of the interval
                self.timing[name] = Timing(timing.interval_s, timing.base_s, timing.index + 1)
            else:  # aperiodic: unknown until the FMU tells
                self.timing[name] = Timing()

    def _read_outputs(self, t: float) -> list[str]:
        """The output clocks active now (logged as ticks)."""
        if not self.outputs:
            return []
        fmu, component = self._backend.fmu, self._backend.component
        vrs, values = self._output_buf
        self._call("fmi3GetClock", lambda: fmu.fmi3GetClock(component, vrs, len(self.outputs), values))
        fired = [v.name for v, active in zip(self.outputs, values, strict=True) if active]
        self._log(t, fired)
        return fired

    def _hold(self, clocks: Iterable[str] | None) -> None:
        """Read the clocked variables of ``clocks`` (all of them: None) while they may be read, and
        hold them until their clocks tick again: FMI 3.0 lets an importer read a clocked variable
        only while its clock is active."""
        if self.read_values is None:
            return
        names = self._clocked if clocks is None else clocks
        key = tuple(names)
        reader = self._readers.get(key)
        if reader is None:  # one reader per set of clocks that tick together, built once
            variables = list(dict.fromkeys(v for n in names for v in self._clocked.get(n, ())))
            reader = (variables, self.read_values(variables) if variables else None)
            self._readers[key] = reader
        variables, group = reader
        if group is None:
            return
        values, position = group.read(), 0
        for var in variables:
            convert = _CONVERT.get(var.type, float)
            self.held[var.name] = [convert(x) for x in values[position : position + var.size]]
            position += var.size

    def _read_intervals(self, t: float, activated: set[str]) -> None:
        """The intervals FMI 3.0 says to ask for at an event: countdown clocks always, tunable clocks
        whose interval the FMU computes, changing clocks that just ticked."""
        for var, kind in self._asked:
            if kind == "changing" and var.name not in activated:
                continue
            interval, qualifier = self._interval(var)
            if qualifier != CHANGED:
                continue
            if kind == "tunable":  # a new interval counts from this event
                self.timing[var.name] = Timing(interval_s=interval, base_s=t, index=1)
            else:
                self.timing[var.name] = Timing(next_s=t + interval)

    # -- FMI calls -----------------------------------------------------------------------------------
    def _interval(self, var: Variable) -> tuple[float, int]:
        fmu, component = self._backend.fmu, self._backend.component
        vrs, (interval, qualifier) = self._vr[var.name], self._interval_buf
        self._call(
            f"fmi3GetIntervalDecimal({var.name})",
            lambda: fmu.fmi3GetIntervalDecimal(component, vrs, 1, interval, qualifier),
        )
        return float(interval[0]), int(qualifier[0])

    def _shift(self, var: Variable) -> float:
        fmu, component = self._backend.fmu, self._backend.component
        vrs, shift = _vrs([var]), (fmi3.fmi3Float64 * 1)()
        self._call(
            f"fmi3GetShiftDecimal({var.name})", lambda: fmu.fmi3GetShiftDecimal(component, vrs, 1, shift)
        )
        return float(shift[0])

    def _call(self, what: str, fn: Callable[[], Any]) -> Any:
        """An FMI call; FMPy's exceptions become :class:`FmuError` with the time and the FMU's log."""
        try:
            return fn()
        except FmuError:
            raise
        except Exception as exc:
            raise FmuError(
                f"{self.info.model_name}: {what} at t={self._time:g} s failed ({exc})",
                log=self._backend.log.recent(),
            ) from exc

    def _log(self, t: float, names: Iterable[str]) -> None:
        for name in names:
            self.ticks.append((t, name))
            self._logged += 1


class ClockInputs:
    """Inputs of a sample where some are triggered input clocks: a clock's value above 0.5 ticks it
    at the current time, before the next step (an agent's action); the others are written as the
    :class:`~bridge.fmu.signals.SignalGroup` ``numeric`` does."""

    def __init__(self, driver: ClockDriver, names: Sequence[str], numeric: Any) -> None:
        self.names = tuple(names)
        self._driver, self._numeric = driver, numeric
        self._clocks = [(i, n) for i, n in enumerate(names) if n in driver.triggered]
        self._others = [i for i, n in enumerate(names) if n not in driver.triggered]

    def write(self, values: Sequence[float]) -> None:
        if self._numeric is not None:
            self._numeric.write([values[i] for i in self._others])
        for i, name in self._clocks:
            if values[i] > 0.5:
                self._driver.activate(name)

    def native_buffer(self, *, writing: bool) -> None:
        """No native sample: the clocks tick in Python."""
        return None


class ClockedOutputs:
    """Outputs of a sample where some are clocked variables: those come from the values the driver
    read at their clocks' last tick (:attr:`ClockDriver.held`), the others from the FMU now through
    the :class:`~bridge.fmu.signals.SignalGroup` ``numeric``."""

    def __init__(
        self,
        driver: ClockDriver,
        names: Sequence[str],
        elements: Sequence[tuple[Variable, int | None]],
        numeric: Any,
    ) -> None:
        self.names = tuple(names)
        self._driver, self._numeric = driver, numeric
        self._held = [(i, var.name, index or 0) for i, (var, index) in enumerate(elements) if var.clocks]
        self._others = [i for i, (var, _) in enumerate(elements) if not var.clocks]
        self._values = np.zeros(len(self.names), dtype=np.float64)

    def __len__(self) -> int:
        return len(self.names)

    def read(self) -> npt.NDArray[np.float64]:
        values = self._values
        if self._numeric is not None:
            values[self._others] = self._numeric.read()
        held = self._driver.held
        for i, name, index in self._held:
            value = held.get(name)
            if value is None:
                raise FmuError(
                    f"{self._driver.info.model_name}: clocked variable {name!r} has no value yet: the FMU "
                    f"did not give one in initialization mode and its clock has not ticked; observe it "
                    f"from its clock's first tick on, or leave it out of the observations"
                )
            values[i] = float(value[index])
        copied: npt.NDArray[np.float64] = values.copy()
        return copied

    def read_into(self, out: npt.NDArray[np.float64]) -> None:
        out[:] = self.read()

    def native_buffer(self, *, writing: bool) -> None:
        """No native sample: the clocks tick in Python."""
        return None


_CONVERT: dict[str, Callable[[Any], Any]] = {"Boolean": bool} | {
    t: int for t in ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Enumeration")
}


def _priority(var: Variable) -> tuple[int, int]:
    return (var.clock.priority if var.clock is not None else 0, var.value_reference)


def _vrs(variables: Sequence[Variable]) -> Any:
    return (fmi3.fmi3ValueReference * len(variables))(*(v.value_reference for v in variables))


__all__ = [
    "CHANGED",
    "ERROR",
    "NOT_YET_KNOWN",
    "UNCHANGED",
    "ClockDriver",
    "ClockInputs",
    "ClockedOutputs",
    "Timing",
    "check_settings",
    "clock_driver_needed",
]


def clock_driver(
    backend: Any,
    info: ModelInfo,
    interface: str,
    intervals: Mapping[str, float] | None,
    schedule: Mapping[str, Sequence[float]] | None,
) -> ClockDriver | None:
    """The clock driver of an instance (``backend``) where its FMU's clocks tick in this interface
    (None where none do); ``intervals`` and ``schedule`` are refused where they have no clocks to set."""
    if clock_driver_needed(info, interface):
        driver = ClockDriver(backend, info, interface, intervals=intervals, schedule=schedule)
        backend.clock_update = driver.clock_update
        return driver
    if intervals or schedule:
        raise ConfigError(
            f"{info.model_name}: clock_intervals and clock_schedule need FMI 3.0 input clocks "
            f"in co-simulation with event mode or in scheduled execution; this FMU runs "
            f"FMI {info.fmi_version} {interface.upper()} without them"
        )
    return None
