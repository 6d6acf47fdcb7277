"""``Model``: one FMU instance with typed variable access, integer-indexed stepping and resets.

Time is an integer: after ``k`` FMU steps of size ``h`` the model is at ``t = t0 + k * h``
(never accumulated). A sample of an agent is ``n`` FMU steps (``advance(n)``). ``k`` lives in one
C ``long long`` (the model's clock) that the native steppers (``bridge.fmu.sample``,
``bridge.fmu.batch``) advance in place, so whoever steps the instance, the model knows its time.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import math
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from bridge.errors import FMU_LOG_HEADER, ConfigError, FmuError, StepError, VariableError
from bridge.fmu import access, archive, once, python_backed, serial, start_state, structure
from bridge.fmu.abi import DISCARD, FATAL, STATUS_NAMES, WARNING, Clock, address, pointer_value
from bridge.fmu.backend import Backend, open_backend
from bridge.fmu.clocks import ClockDriver, ClockedOutputs, ClockInputs, clock_driver_needed
from bridge.fmu.description import Interface, ModelInfo, Variable, read_model_info, unknown_variable_error
from bridge.fmu.events import EventCalls
from bridge.fmu.fixed_step import METHODS, FixedStepper
from bridge.fmu.signals import SignalGroup
from bridge.fmu.solver import MeStepper
from bridge.fmu.spec import ResetPolicy, Solver
from bridge.fmu.state_file import MAX_STATE_BYTES, StateFile
from bridge.fmu.values import to_c

_log = logging.getLogger(__name__)

RESET_POLICIES: tuple[str, ...] = ("auto", "reset", "restore", "reinstantiate")
SOLVERS: tuple[str, ...] = ("cvode", *METHODS)
_counter = itertools.count(1)
_MAX_SNAPSHOTS = 8
# An FMU state and, for model exchange, the next time event it had announced (not part of the state).
_Snapshot = tuple[ctypes.c_void_p, float | None]


@dataclass
class _ResetTrust:
    """What ``reset_policy: auto`` has seen of the FMU's reset: a snapshot is taken of a fresh
    instance's initialisation, never of a state not yet seen to work. An fmi reset is trusted until
    an episode begun by it terminates at its first step where a fresh instance ran longer (the FMU
    kept its terminated flag); then ``auto`` re-instantiates instead."""

    origin: Literal["fresh", "fmi_reset", "restore"] = "fresh"  # how the current episode began
    fresh_steps: int | None = None  # steps of a fresh instance's episode that ended by termination
    fmi_reset_works: bool = True
    snapshots_work: bool = True  # get_state after an fmi reset succeeded (or was not tried)
    pending: tuple[tuple[Any, ...], _Snapshot] | None = None  # candidate snapshot after fmi reset


@dataclass
class ModelState:
    """A saved state of one :class:`Model` (``Model.save_state``): the FMU's own state, the step
    index and, for model exchange, the next time event. Free it with ``Model.free_state``."""

    handle: ctypes.c_void_p | None
    step_index: int
    terminated: bool
    next_event_s: float | None
    clocks: tuple[Any, ...] | None = None  # the clock schedule (FMUs with clocks that tick)


class Model:
    """One instance of an FMU (FMI 1.0/2.0/3.0, co-simulation or model exchange).

    Args:
        path: the .fmu archive (or an extracted FMU directory).
        step_size_s: FMU step size ``h`` in seconds; defaults to the FMU's default experiment.
        start_time_s: ``t0``; defaults to the default experiment's start time, else 0.
        stop_time_s: passed to the FMU at initialisation when given.
        interface: ``"cs"``, ``"me"`` or ``"auto"`` (co-simulation where the FMU has it).
        reset_policy: ``"restore"`` a state snapshot taken after initialisation, fmi ``"reset"``,
            ``"reinstantiate"``, or ``"auto"``: restore where the FMU can get/set its state
            (snapshots are taken for value sets seen more than once), else reset.
        tolerance: relative tolerance for the FMU (and the ODE solver, for model exchange).
        solver: model exchange only: ``"cvode"`` (variable step, the default), or ``"rk4"`` /
            ``"euler"``: fixed steps of ``step_size_s / solver_substeps`` in native code
            (``bridge.fmu.fixed_step``; FMI 2.0/3.0).
        solver_substeps: fixed-step integration steps per FMU step.
        instance_name: the FMU instance's name (default: ``<model name>#<counter>``).
        structural_parameters: FMI 3.0 structural parameters (array sizes) by name, set in
            configuration mode after every instantiation and fmi reset; :attr:`info` then holds the
            array sizes the FMU reports (``bridge.fmu.structure``).
        clock_intervals: FMI 3.0 fixed/tunable input clocks with an ``intervalDecimal``: the
            interval (s) to set in initialization mode instead of the XML's.
        clock_schedule: FMI 3.0 triggered input clocks: the times (s) at which to activate them.

    FMI 3.0 clocks tick in co-simulation with event mode and in scheduled execution
    (``interface="se"``, chosen by ``"auto"`` for an FMU that offers nothing else): see
    :mod:`bridge.fmu.clocks`; :attr:`clock_ticks` lists the ticks since the start.

    The model keeps the only clock of its instance: :attr:`step_index` ``k`` (time
    ``t0 + k * h``), advanced by :meth:`advance` and, in place, by the native steppers of this
    package (``bridge.fmu.sample``, ``bridge.fmu.batch``).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        step_size_s: float | None = None,
        start_time_s: float | None = None,
        stop_time_s: float | None = None,
        interface: Interface | Literal["auto"] = "auto",
        reset_policy: ResetPolicy = "auto",
        tolerance: float | None = None,
        instance_name: str | None = None,
        solver: Solver = "cvode",
        solver_substeps: int = 1,
        structural_parameters: Mapping[str, int] | None = None,
        clock_intervals: Mapping[str, float] | None = None,
        clock_schedule: Mapping[str, Sequence[float]] | None = None,
    ) -> None:
        self.info: ModelInfo = read_model_info(path)
        python_backed.check_requirements(self.info)  # its missing packages named before it loads
        self._structural = structure.check(self.info, structural_parameters) if structural_parameters else {}
        self._configured = False  # structural parameters applied (sizes in info) at least once
        self._initialized_once = False
        self.interface: Interface = _choose_interface(self.info, interface)
        self.step_size_s = _step_size(self.info, step_size_s)
        de = self.info.default_experiment
        self.start_time_s = float(start_time_s if start_time_s is not None else de.start_time_s or 0.0)
        self.stop_time_s = stop_time_s
        self._requested_tolerance = tolerance
        self.tolerance = tolerance if tolerance is not None else de.tolerance
        if reset_policy not in RESET_POLICIES:
            raise ConfigError(f"reset_policy {reset_policy!r} is unknown; expected one of {RESET_POLICIES}")
        self.reset_policy: ResetPolicy = reset_policy
        self.solver, self.solver_substeps = _check_solver(self.info, self.interface, solver, solver_substeps)
        self.can_restore = self.info.can_get_set_state.get(self.interface, False) and self.info.fmi_major >= 2
        self._clock = Clock(0)
        self.terminated = False
        self._initialized = False
        self._init_failed = False
        self._closed = False
        self._failed_status = 0
        self._snapshots: OrderedDict[tuple[Any, ...], _Snapshot | None] = OrderedDict()
        self._trust = _ResetTrust()
        self._me: MeStepper | FixedStepper | None = None
        self._handles: tuple[Any, dict[str, int]] | None = None  # (the instance, its addresses)
        self._inputs_dirty = False
        self._init_values: dict[str, Any] = {}  # of the last initialisation, for state files
        self._start: start_state.StartState | None = None  # episodes start from a state file
        name = instance_name or f"{self.info.model_name}#{next(_counter)}"
        once.claim(self.info, self)  # canBeInstantiatedOnlyOncePerProcess: refused if one is open
        self._unzip = archive.acquire(self.info.path)
        try:
            self._backend: Backend = open_backend(self.info, self._unzip, self.interface, name)
        except BaseException:
            archive.release(self.info.path)
            once.release(self.info, self)
            raise
        self._do_step = self._backend.stepper() if self.interface == "cs" else self._backend.do_step
        if self._structural:  # the array sizes decide every signal's layout: configure before any use
            try:
                self._backend.instantiate()
                self._configure()
            except BaseException:
                self.close()
                raise
        self._clocks: ClockDriver | None = self._clocks_for(clock_intervals, clock_schedule)

    def _clocks_for(
        self, intervals: Mapping[str, float] | None, schedule: Mapping[str, Sequence[float]] | None
    ) -> ClockDriver | None:
        if clock_driver_needed(self.info, self.interface):
            return self._start_clocks(intervals, schedule)
        if intervals or schedule:
            self.close()
            raise ConfigError(
                f"{self.info.model_name}: clock_intervals and clock_schedule need FMI 3.0 input clocks "
                f"in co-simulation with event mode or in scheduled execution; this FMU runs "
                f"FMI {self.info.fmi_version} {self.interface.upper()} without them"
            )
        return None

    def _start_clocks(
        self, intervals: Mapping[str, float] | None, schedule: Mapping[str, Sequence[float]] | None
    ) -> ClockDriver:
        try:
            driver = ClockDriver(
                self._backend, self.info, self.interface, intervals=intervals, schedule=schedule
            )
        except BaseException:
            self.close()
            raise
        backend: Any = self._backend
        backend.clock_update = driver.clock_update
        driver.read_values = self._clocked_reader
        self._do_step = driver.step
        return driver

    # -- context management -------------------------------------------------------------------
    def __enter__(self) -> Model:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Free the instance, its snapshots and the library; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        was_initialized, self._initialized = self._initialized, False
        self._drop_snapshots()
        if self._start is not None:
            start_state.free(self, self._start)
        self._me = None
        try:
            if was_initialized and self._failed_status < FATAL:
                self._backend.fmu.terminate()
        except Exception:
            _log.debug("terminate failed while closing %s", self.info.model_name, exc_info=True)
        try:
            self._backend.free_instance()
            self._backend.unload()
        finally:
            archive.release(self.info.path)
            once.release(self.info, self)

    def _clocked_reader(self, variables: list[Variable]) -> SignalGroup:
        """A reader of clocked variables for the clock driver (it reads them while their clocks tick)."""
        names = [n for v in variables for n in (v.element_names() if v.dimensions else [v.name])]
        return SignalGroup(self, [self._element(n) for n in names], names)

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

    def _attach_clock(self, clock: Clock) -> None:
        """Keep ``k`` in ``clock`` from now on (a cell of a batch's array), carrying its value over."""
        clock.value = self._clock.value
        self._clock = clock

    # -- variables ----------------------------------------------------------------------------

    @property
    def log(self) -> list[str]:
        """The FMU's most recent log messages."""
        return list(self._backend.log.messages)

    def variable(self, name: str) -> Variable:
        return self.info.variable(name)

    def signals(self, names: Sequence[str], *, writable: bool = False, role: str = "signal") -> SignalGroup:
        """A batched accessor for numeric variables and array elements ``y[2,3]`` (:class:`SignalGroup`).

        Writable groups may name FMI 3.0 triggered input clocks: a value above 0.5 ticks the clock
        before the next step (:class:`bridge.fmu.clocks.ClockInputs`).
        """
        clocks = self._clocks
        if writable and clocks is not None and any(n in clocks.triggered for n in names):
            others = [n for n in names if n not in clocks.triggered]
            numeric = self.signals(others, writable=True, role=role) if others else None
            return ClockInputs(clocks, names, numeric)  # type: ignore[return-value]
        elements = [self._element(n, role) for n in names]
        if not writable and clocks is not None and any(var.clocks for var, _ in elements):
            others = [n for n, (var, _) in zip(names, elements, strict=True) if not var.clocks]
            numeric = self.signals(others, role=role) if others else None
            return ClockedOutputs(clocks, names, elements, numeric)  # type: ignore[return-value]
        if not elements and not writable:  # an empty input group: an observation-only experiment
            raise ConfigError(f"{role}: at least one variable is needed")
        for var, _ in elements:
            if not var.is_numeric:
                raise VariableError(
                    f"{role} {var.name!r} is a {var.type} variable: signal groups are numeric "
                    f"(Float, Int, Boolean, Enumeration); read it with Model.get()"
                )
            if writable and not var.settable_in_step:
                raise VariableError(_not_settable_in_step(var, self.info))
        return SignalGroup(self, elements, list(names))

    def get(self, names: Iterable[str]) -> dict[str, Any]:
        """Current values by name, typed (float, int, bool, str, bytes for Binary).

        An FMI 3.0 array by its name gives a numpy array of its shape; ``y[2,3]`` (1-based indices,
        one per dimension) gives one element.
        """
        wanted = {name: self._element(name) for name in names}
        variables = list(dict.fromkeys(var for var, _ in wanted.values()))
        held = self._clocks.held if self._clocks is not None else {}
        flat = access.read(self._backend, [v for v in variables if v.name not in held], self._where)
        flat.update((v.name, held[v.name]) for v in variables if v.name in held)  # read at the last tick
        return {name: access.pick(var, flat[var.name], index) for name, (var, index) in wanted.items()}

    def set(self, values: Mapping[str, Any]) -> None:
        """Set inputs or tunable parameters between steps (one FMI call per type).

        Array elements are written as ``{"u[2]": 1.5}``, whole arrays as ``{"u": [...]}``.
        """
        elements = {name: self._element(name) for name in values}
        for var, _ in elements.values():
            if not var.settable_in_step:
                raise VariableError(_not_settable_in_step(var, self.info))
        variables = list(dict.fromkeys(var for var, _ in elements.values()))
        flat = access.merge(self._backend, elements, values, self._to_c, self._where)
        clocks = self._clocks
        if clocks is not None and self._initialized and any(v.variability != "continuous" for v in variables):
            clocks.write_in_event_mode(lambda: access.write(self._backend, variables, flat, self._where))
            return
        if self.interface == "me" and any(v.variability != "continuous" for v in variables):
            self.write_in_event_mode(lambda: access.write(self._backend, variables, flat, self._where))
            return
        access.write(self._backend, variables, flat, self._where)
        if self.interface == "me":
            self._inputs_dirty = True

    def _where(self) -> str:
        return f"at step {self.step_index} (t={self.time_s:g} s)"

    def _element(self, name: str, role: str = "variable") -> tuple[Variable, int | None]:
        try:
            return self.info.element(name)
        except VariableError:
            if name not in self.info.variables and "[" not in name:
                raise unknown_variable_error(name, self.info, role) from None
            raise

    def write_in_event_mode(self, write: Callable[[], None]) -> None:
        """Model exchange: ``write`` in event mode, then the discrete-state iteration and continuous time.

        FMI 2.0/3.0 accept discrete inputs and tunable parameters only in event mode; FMI 1.0 takes
        them at any time but needs the event iteration afterwards.
        """
        me = self._me
        if me is None or self.terminated:  # before initialisation every value is accepted
            write()
            return
        events, call = me.events, self._backend.call
        call("enterEventMode", events.enter_event_mode)
        write()
        terminate, me.next_event_s = call("the event iteration", events.iterate)
        self._inputs_dirty = True
        if terminate:
            self.terminated = True
            return
        call("enterContinuousTimeMode", events.enter_continuous_time_mode)

    def _to_c(self, var: Variable, value: Any) -> Any:
        return to_c(var, value, self.info.model_name, self._backend.major)

    def _write(self, variables: Sequence[Variable], values: Mapping[Variable, Any]) -> None:
        """Initial values: scalars, whole arrays, and array elements over the array's current values."""
        if not variables:
            return
        partial = [v for v in variables if isinstance(values[v], _Elements)]
        current = access.read(self._backend, partial, self._where) if partial else {}
        flat: dict[str, list[Any]] = {}
        for v in variables:
            value = values[v]
            if isinstance(value, _Elements):
                row = [self._to_c(v, x) for x in current[v.name]]
                for index, x in value.items:
                    row[index] = self._to_c(v, x)
                flat[v.name] = row
            elif v.dimensions:
                flat[v.name] = [self._to_c(v, x) for x in _whole_array(v, value)]
            else:
                flat[v.name] = [self._to_c(v, value)]
        access.write(self._backend, list(variables), flat, self._where)

    def _inputs_written(self) -> None:
        self._inputs_dirty = True

    # -- initialisation and reset -------------------------------------------------------------
    def initialize(self, values: Mapping[str, Any] | None = None) -> None:
        """Instantiate (first call) and initialise with parameters and start values ``values``."""
        if self._closed:
            raise FmuError(f"{self.info.model_name}: the model is closed; open a new Model")
        checked = self._check_init_values(values or {})
        if self._backend.component is not None and self.unusable:
            # a failed initialisation leaves the instance half-initialised for good: start afresh
            _log.info("%s: re-instantiating after a failed initialisation", self.info.model_name)
            self._reinstantiate(checked)
        else:
            if self._backend.component is None:
                self._backend.instantiate()
            self._initialize(checked)
        self._trust.origin = "fresh"
        self._remember(_freeze(checked))

    @property
    def unusable(self) -> bool:
        """True after a failed initialisation: the instance cannot step until the next reset,
        which instantiates it afresh."""
        return self._init_failed

    def reset(self, values: Mapping[str, Any] | None = None) -> None:
        """Return to ``t0`` with parameters/start values ``values``, by the configured policy
        (or to the saved state of :meth:`start_from`)."""
        if self._start is not None:
            start_state.restore(self, self._start, dict(values or {}))
            return
        if not self._initialized:
            self.initialize(values)
            return
        checked = self._check_init_values(values) if values else {}
        key = _freeze(checked) if checked else ()
        if self.reset_policy in ("auto", "reset"):
            self._judge_episode()
        snapshot = self._snapshots.get(key) if self._failed_status == 0 else None
        restoring = snapshot is not None and self.reset_policy in ("auto", "restore")
        if restoring and self._restored(key, snapshot):  # type: ignore[arg-type]
            return
        policy = self.reset_policy
        trust = self._trust
        fresh = policy == "reinstantiate" or self._failed_status >= FATAL or self.info.fmi_major == 1
        if fresh or (policy == "auto" and not trust.fmi_reset_works):
            self._reinstantiate(checked)
        else:
            try:
                self._backend.reset()
                self._initialize(checked)
                if policy in ("auto", "reset") and self._kept_termination():
                    fresh = self._reset_kept_termination(checked)
            except FmuError as exc:
                said = str(exc).partition(FMU_LOG_HEADER)[0]  # the log comes with the error, if it stays
                _log.warning("%s: the FMU's reset failed (%s); re-instantiating", self.info.model_name, said)
                self._reinstantiate(checked)
                fresh = True
        trust.origin = "fresh" if fresh or not trust.fmi_reset_works else "fmi_reset"
        self._remember(key)

    def _kept_termination(self) -> bool:
        trusted = self._trust.fmi_reset_works
        return trusted and self.interface == "cs" and self._backend.reports_terminated()

    def _reset_kept_termination(self, checked: dict[Variable, Any]) -> bool:
        """The FMU reports a terminated run right after fmi reset: ``auto`` re-instantiates (True);
        ``reset`` keeps the user's policy and says why its episodes will end at once (False)."""
        self._distrust_reset("still reports a terminated run after fmi reset and initialisation")
        if self.reset_policy != "auto":
            return False
        self._reinstantiate(checked)
        return True

    def _distrust_reset(self, why: str) -> None:
        self._trust.fmi_reset_works = False
        if self.reset_policy == "auto":
            fix = "re-instantiating instead (set reset_policy to restore or reinstantiate to say so)"
        else:
            fix = "episodes after a reset end at once: set reset_policy to auto, restore or reinstantiate"
        _log.warning("%s: the FMU %s; %s", self.info.model_name, why, fix)

    def _restored(self, key: tuple[Any, ...], snapshot: _Snapshot) -> bool:
        """Back to the snapshot of ``key``; False (snapshots dropped) where the FMU refused it under
        ``auto`` (some FMUs refuse their state functions once fmi-reset)."""
        self._snapshots.move_to_end(key)
        state, next_event_s = snapshot
        try:
            self._backend.set_state(state)
        except FmuError as exc:
            if self.reset_policy != "auto":
                raise
            _log.warning("%s: restoring a snapshot failed (%s); re-instantiating", self.info.model_name, exc)
            self._drop_snapshots()
            self._trust.fmi_reset_works = False  # the reset left state functions unusable
            return False
        self._clock.value, self.terminated = 0, False  # _restart() inlined: the reset hot path
        if self._me is not None:
            self._me.restart(self.start_time_s)
            self._me.next_event_s = next_event_s
        if self._clocks is not None:
            self._clocks.rewind(self.start_time_s)
        self._trust.origin = "restore"
        return True

    def _judge_episode(self) -> None:
        """``auto``: what the episode now ending shows (:class:`_ResetTrust`); a candidate snapshot
        taken after an fmi reset is kept only if its episode ran a step without terminating."""
        trust, steps, ended = self._trust, self.step_index, self.terminated
        if trust.origin == "fresh" and ended:
            trust.fresh_steps = steps
        first_step_ended = trust.origin == "fmi_reset" and ended and steps <= 1
        longer_when_fresh = trust.fresh_steps is None or trust.fresh_steps > 1
        if first_step_ended and trust.fmi_reset_works and longer_when_fresh:
            ran = trust.fresh_steps if trust.fresh_steps is not None else "more"
            self._distrust_reset(
                f"asked to terminate at the first step after fmi reset, though a fresh instance ran "
                f"{ran} steps: its reset keeps a terminated run"
            )
        pending, trust.pending = trust.pending, None
        if pending is None:
            return
        key, snapshot = pending
        ran = steps > 1 or (steps == 1 and not ended)
        if trust.fmi_reset_works and trust.origin == "fmi_reset" and ran:
            self._snapshots[key] = snapshot
            self._snapshots.move_to_end(key)
            self._evict()
        else:
            self._backend.free_state(snapshot[0])

    def _reinstantiate(self, values: dict[Variable, Any]) -> None:
        self._drop_snapshots()
        self._backend.free_instance()
        self._backend.instantiate()
        self._initialize(values)

    def _configure(self) -> None:
        """Structural parameters in configuration mode; the FMU's array sizes into :attr:`info`."""
        backend, values = self._backend, self._structural
        wanted = structure.integer_structural(self.info)
        backend.call("fmi3EnterConfigurationMode", backend.fmu.enterConfigurationMode)
        try:
            flat = {v.name: [self._to_c(v, value)] for v, value in values.items()}
            access.write(backend, list(values), flat, self._where)
            read = access.read(backend, wanted, self._where)  # the sizes the FMU reports, not what was asked
        finally:
            backend.call("fmi3ExitConfigurationMode", backend.fmu.exitConfigurationMode)
        sizes = {v.value_reference: int(read[v.name][0]) for v in wanted}
        wrong = structure.refused(self.info, values, sizes)
        if wrong is not None:
            raise FmuError(wrong, log=backend.log.recent())
        info = structure.resized(self.info, sizes)
        if self._configured and info != self.info:
            raise FmuError(f"{self.info.model_name}: the FMU changed its array sizes on reconfiguration")
        self.info = self._backend.info = info
        self._configured = True

    def _initialize(self, values: dict[Variable, Any]) -> None:
        self._initialized = False
        self._init_failed = True  # until it completes
        self._backend.log.clear()
        if self._structural and not self._fresh_configuration():
            self._configure()  # instantiated or fmi reset: structural parameters are back at their starts
        # FMI 1.0 takes every start value before fmiInitialize; 2.0/3.0 calculated ones in init mode,
        # and array elements there too: the other elements are read first, which FMI 3.0 allows
        # only from initialisation mode on.
        early = [
            v
            for v in values
            if not isinstance(values[v], _Elements)
            and (self._backend.major == 1 or v.causality == "input" or v.initial in ("exact", "approx"))
        ]
        late = [v for v in values if v not in early]
        self._init_values = _by_name(values)
        self._write(early, values)
        # Tolerance steers a co-simulation FMU's own solver; for model exchange it is ours (CVode).
        tolerance = self.tolerance if self.interface == "cs" else None
        self._backend.enter_initialization(self.start_time_s, self.stop_time_s, tolerance)
        self._write(late, values)
        if self._clocks is not None:
            self._clocks.configure(self.start_time_s)
        self._backend.exit_initialization()
        if self._clocks is not None:  # model exchange: the clocks due at the start, in event mode
            self._clocks.start(self.start_time_s)
        if self.interface == "me":
            self._start_me()
        self._initialized = True
        self._init_failed = False
        self._failed_status = 0
        self._restart()

    def _start_me(self) -> None:
        # FMI 2.0 and 3.0 both leave initialisation in event mode: iterate, then integrate.
        # FMI 1.0's fmiInitialize has iterated already (the backend finished it).
        fmu, backend = self._backend.fmu, self._backend
        events = EventCalls(fmu, backend.major)
        if backend.major == 1:
            terminate, next_event = getattr(backend, "initial_events", (False, None))
        else:
            terminate, next_event = backend.call("the initial event iteration", events.iterate)
        if terminate:
            raise FmuError(f"{self.info.model_name}: the FMU requested termination during initialisation")
        backend.call("enterContinuousTimeMode", events.enter_continuous_time_mode)
        if self._me is None or self._me.fmu is not fmu:
            self._me = self._me_stepper(next_event)
        else:
            self._me.next_event_s = next_event

    def _fresh_configuration(self) -> bool:
        """True once, right after the configuration made when the model was opened."""
        fresh = self._configured and not self._initialized_once
        self._initialized_once = True
        return fresh

    def _resume_me(self, next_event_s: float | None) -> None:
        """Integrate on from the current time after a state was set in place of an initialisation."""
        if self._me is None or self._me.fmu is not self._backend.fmu:
            self._me = self._me_stepper(next_event_s)
        self._me.restart(self.time_s)
        self._me.next_event_s = next_event_s

    def _me_stepper(self, next_event: float | None) -> MeStepper | FixedStepper:
        if self.solver != "cvode":
            h = self.step_size_s
            return FixedStepper(self._backend, self.solver, self.solver_substeps, h, next_event)
        # An exporter's default tolerance is tuned for its own solver; restarting CVode at every
        # input change needs a tighter one, so 1e-6 unless the caller asks for another.
        tolerance = self._requested_tolerance or min(self.tolerance or 1e-6, 1e-6)
        return MeStepper(self._backend, self.start_time_s, tolerance, self.step_size_s, next_event)

    def _restart(self) -> None:
        self.step_index = 0
        self.terminated = False
        if self._me is not None:
            self._me.restart(self.start_time_s)

    def _check_init_values(self, values: Mapping[str, Any]) -> dict[Variable, Any]:
        """Parameters and start values by variable: scalars, whole FMI 3.0 arrays, and array
        elements (``A[1,2]``, named as actions name them) gathered per array as :class:`_Elements`."""
        checked: dict[Variable, Any] = {}
        elements: dict[Variable, dict[int, Any]] = {}
        for name, value in values.items():
            var, index = self._element(name, "parameter or start value")
            if not var.settable_at_init:
                raise VariableError(_not_settable_at_init(var, self.info))
            if index is not None:
                self._to_c(var, value)
                elements.setdefault(var, {})[index] = value
                continue
            for x in _whole_array(var, value) if var.dimensions else [value]:
                self._to_c(var, x)
            checked[var] = value
        for var, items in elements.items():
            if var in checked:
                raise VariableError(
                    f"{var.name!r} of {self.info.model_name} is given both whole and by element; "
                    f"give one or the other"
                )
            checked[var] = _Elements(tuple(sorted(items.items())))
        return checked

    def _remember(self, key: tuple[Any, ...]) -> None:
        """Snapshot the state right after initialisation: ``restore`` always; ``auto`` after an
        initialisation of a fresh instance, and after an fmi reset for value sets that recur, as a
        candidate kept once its episode has run (:meth:`_judge_episode`)."""
        if not self.can_restore or self.reset_policy not in ("auto", "restore"):
            return
        if self._snapshots.get(key) is not None:
            return
        if self.reset_policy == "auto" and self._trust.origin != "fresh":
            if key not in self._snapshots:
                self._snapshots[key] = None  # first sighting: remember the key, a candidate on the next
                self._evict()
            elif self._trust.snapshots_work and (candidate := self._candidate()) is not None:
                self._trust.pending = (key, candidate)
            return
        next_event_s = self._me.next_event_s if self._me is not None else None
        self._snapshots[key] = (self._backend.get_state(), next_event_s)
        self._snapshots.move_to_end(key)
        self._evict()

    def _candidate(self) -> _Snapshot | None:
        try:
            state = self._backend.get_state()
        except FmuError as exc:  # some FMUs refuse their state functions once fmi-reset
            _log.info("%s: no snapshot after fmi reset (%s)", self.info.model_name, exc)
            self._trust.snapshots_work = False
            return None
        return (state, self._me.next_event_s if self._me is not None else None)

    def _evict(self) -> None:
        while len(self._snapshots) > _MAX_SNAPSHOTS:
            _, snapshot = self._snapshots.popitem(last=False)
            if snapshot is not None:
                self._backend.free_state(snapshot[0])

    def _drop_snapshots(self) -> None:
        pending, self._trust.pending = self._trust.pending, None
        for snapshot in [*self._snapshots.values(), pending[1] if pending else None]:
            if snapshot is not None:
                self._backend.free_state(snapshot[0])
        self._snapshots.clear()

    # -- saved states (rollback) ---------------------------------------------------------------
    def save_state(self) -> ModelState:
        """The state now (FMU state, step index, time); needs ``can_restore`` (FMI 2.0/3.0 FMUs
        with canGetAndSetFMUstate), else :class:`FmuError`. Free it with :meth:`free_state`."""
        if not self.can_restore or not self._initialized:
            why = "is not initialised" if self.can_restore else "cannot get and set its state"
            raise FmuError(
                f"{self.info.model_name}: cannot save the state: the FMU {why} "
                f"(canGetAndSetFMUstate={self.can_restore}) [{self.info.path}]"
            )
        next_event_s = self._me.next_event_s if self._me is not None else None
        clocks = self._clocks.save() if self._clocks is not None else None
        return ModelState(self._backend.get_state(), self.step_index, self.terminated, next_event_s, clocks)

    def restore_state(self, state: ModelState) -> None:
        """Back to ``state`` (from :meth:`save_state` of this model, not yet freed)."""
        if state.handle is None or self._closed:
            raise FmuError(f"{self.info.model_name}: cannot restore a freed state or into a closed model")
        self._backend.set_state(state.handle)
        self.step_index, self.terminated = state.step_index, state.terminated
        if self._failed_status < FATAL:
            self._failed_status = 0
        if self._me is not None:
            self._me.restart(self.time_s)
            self._me.next_event_s = state.next_event_s
        if self._clocks is not None and state.clocks is not None:
            self._clocks.load(state.clocks)

    def free_state(self, state: ModelState) -> None:
        """Release ``state``'s memory in the FMU; safe to call twice."""
        if state.handle is not None and not self._closed:
            self._backend.free_state(state.handle)
        state.handle = None

    # -- state files ----------------------------------------------------------------------------
    @property
    def can_serialize(self) -> bool:
        """Whether the FMU can save its state to bytes (canSerializeFMUstate and canGetAndSetFMUstate)."""
        return serial.refusal(self.info, self.interface) is None

    @property
    def serialize_refusal(self) -> str | None:
        """Why the FMU cannot save its state to a file (naming the capability flags), or None."""
        return serial.refusal(self.info, self.interface)

    def state_file(self, state: ModelState | None = None, *, max_bytes: int = MAX_STATE_BYTES) -> StateFile:
        """``state`` (default: the state now) serialised by the FMU, with a header naming the FMU
        and the time grid (``bridge.fmu.state_file``); :class:`StateFileError` where it cannot."""
        return start_state.to_file(self, state, max_bytes)

    def start_from(self, file: StateFile | None, source: str = "the state") -> None:
        """Start every episode from now on at ``file``'s state instead of initialising (None:
        initialise again, on the model's own time grid).

        Raises:
            StateFileError: the state was saved by another FMU, or this FMU cannot deserialise.
        """
        if file is None:
            if self._start is not None:
                start_state.free(self, self._start)
                self.start_time_s = self._start.own_start_time_s
                self._start = None
                self._drop_snapshots()
            return
        start = start_state.prepare(self, file, source)
        if self._start is not None:
            start.own_start_time_s = self._start.own_start_time_s
            start_state.free(self, self._start)
        self._drop_snapshots()
        self._start = start

    # -- stepping -----------------------------------------------------------------------------
    def advance(self, n: int = 1) -> bool:
        """Advance ``n`` FMU steps from the current step index; True if the FMU asked to terminate.

        Raises:
            StepError: the FMU returned Error/Fatal/Discard, or stepping after termination.
        """
        if not self._initialized or self.terminated or self._failed_status:
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

    # -- continuous states (model exchange) -----------------------------------------------------
    def continuous_states(self) -> npt.NDArray[np.float64]:
        """The continuous states ``x`` now (model exchange, initialised), in the FMU's order."""
        x = np.zeros(self.info.number_of_states)
        self._me_call("getContinuousStates", x)
        return x

    def set_continuous_states(self, x: npt.ArrayLike) -> None:
        """Set the continuous states ``x`` (model exchange, in continuous-time mode)."""
        values = np.ascontiguousarray(x, dtype=np.float64)
        if values.shape != (self.info.number_of_states,):
            raise VariableError(
                f"{self.info.model_name}: {self.info.number_of_states} continuous states expected, "
                f"got an array of shape {values.shape}"
            )
        self._me_call("setContinuousStates", values)
        self._inputs_dirty = True

    def derivatives(self) -> npt.NDArray[np.float64]:
        """The state derivatives ``dx/dt`` at the current states and inputs (model exchange)."""
        dx = np.zeros(self.info.number_of_states)
        self._me_call("getContinuousStateDerivatives" if self._backend.major == 3 else "getDerivatives", dx)
        return dx

    def _me_call(self, name: str, array: npt.NDArray[np.float64]) -> None:
        if self.interface != "me" or not self._initialized:
            raise FmuError(
                f"{self.info.model_name}: {name} needs an initialised model-exchange instance "
                f"(open the Model with interface='me' and initialize() it)"
            )
        fmu = self._backend.fmu
        pointer = array.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self._backend.call(name, lambda: getattr(fmu, name)(pointer, len(array)))

    # -- for the native steppers of this package (bridge.fmu.sample, bridge.fmu.batch) ------------
    def _native_handles(self) -> dict[str, int]:
        """Addresses for a native stepper that calls this instance's FMI functions directly.

        Keys: ``component`` (the instance), ``major`` (FMI version), ``set_real``, ``get_real``,
        ``do_step`` and ``bool_status`` (the Float64 set/get, doStep and, for FMI 2.0,
        fmi2GetBooleanStatus; 0 where absent), ``get_state``, ``set_state``, ``free_state`` (the
        FMU state functions; 0 where absent). Valid while the model is open and initialised; the
        same dict while the instance is the same (a reset by restore or fmi reset keeps it).
        In model exchange (fixed-step solvers only) :attr:`_fixed_stepper` integrates.
        """
        b, cached = self._backend, self._handles
        if cached is not None and cached[0] is b.component:  # the same instance: the same addresses
            return cached[1]
        if self._clocks is not None:
            raise FmuError(
                f"{self.info.model_name}: its clocks tick in Python (bridge.fmu.clocks), not natively"
            )
        if b.major < 2 or not b.component or (self.interface == "me" and self._fixed_stepper is None):
            raise FmuError(
                f"{self.info.model_name}: native stepping needs an initialised FMI 2.0/3.0 instance "
                f"(co-simulation, or model exchange with solver 'rk4' or 'euler')"
            )
        v, functions = f"fmi{b.major}", b.functions
        real = "Real" if b.major == 2 else "Float64"
        handles = {
            "component": pointer_value(b.component),
            "major": b.major,
            "set_real": address(functions.get(f"{v}Set{real}")),
            "get_real": address(functions.get(f"{v}Get{real}")),
            "do_step": address(functions.get(f"{v}DoStep")),
            "bool_status": address(functions.get("fmi2GetBooleanStatus")) if b.major == 2 else 0,
            # a system's fixed-point iteration saves and restores the state natively
            "get_state": address(functions.get("fmi2GetFMUstate" if b.major == 2 else "fmi3GetFMUState")),
            "set_state": address(functions.get("fmi2SetFMUstate" if b.major == 2 else "fmi3SetFMUState")),
            "free_state": address(functions.get("fmi2FreeFMUstate" if b.major == 2 else "fmi3FreeFMUState")),
        }
        self._handles = (b.component, handles)
        return handles

    @property
    def _fixed_stepper(self) -> FixedStepper | None:
        """The native fixed-step integrator of a model-exchange instance (solver 'rk4' or
        'euler', once initialised); None otherwise."""
        return self._me if isinstance(self._me, FixedStepper) else None

    def _me_finish(self, code: int, n: int) -> bool:
        """Finish a sample of ``n`` FMU steps from the current step index that a native batch
        loop began with :attr:`_fixed_stepper` and stopped with ``code`` (an event, termination or
        a failure); the model then stands after the sample. True if the FMU asked to terminate.

        Raises:
            StepError: as :meth:`advance` does.
        """
        stepper = self._fixed_stepper
        if stepper is None:
            raise FmuError(f"{self.info.model_name}: no fixed-step integrator to finish the sample with")
        k, t0, h = self.step_index, self.start_time_s, self.step_size_s
        terminated = stepper.finish(code, t0 + k * h, t0 + (k + n) * h, k)
        self.step_index, self.terminated = k + n, terminated
        return terminated

    @property
    def _steppable(self) -> bool:
        """True if :meth:`advance` would step now (open, initialised, not terminated, not failed)."""
        return self._initialized and not self.terminated and not self._failed_status and not self._closed

    def _native_terminated(self) -> None:
        """Account for a native doStep after which the FMU asked to terminate (the clock already
        counts the step): the model refuses further steps until reset."""
        self.terminated = True

    def _native_sampled(self, step_index: int, terminated: bool) -> None:
        """Account a native sample that left the counter it was given at ``step_index`` (the
        system's native master keeps one per component for its call)."""
        self._clock.value = step_index
        if terminated:
            self.terminated = True

    def _native_step_failed(self, status: int) -> bool:
        """Account for a native doStep at the current step index that returned ``status``
        (> Warning): True if the FMU asked to terminate, else :class:`StepError`."""
        return self._step_failed(status)

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
        self._failed_status = status
        raise StepError(
            f"{self.info.model_name}: doStep returned {STATUS_NAMES[status]} at step {self.step_index} "
            f"(t={self.time_s:g} s, h={self.step_size_s:g} s); reset() the model to continue, and see the "
            f"FMU log for the cause [{self.info.path}]",
            step=self.step_index,
            time_s=self.time_s,
            log=self._backend.log.recent(),
        )

    def _refuse_step(self) -> None:
        if self._closed:
            reason = "the model is closed"
        elif not self._initialized:
            reason = "the model is not initialised: call initialize() or reset() first"
        elif self.terminated:
            reason = "the FMU requested termination: reset() before stepping again"
        else:
            reason = f"the previous step failed ({STATUS_NAMES[self._failed_status]}): reset() first"
        raise StepError(
            f"{self.info.model_name}: cannot step at step {self.step_index}: {reason}",
            step=self.step_index,
            time_s=self.time_s,
            log=self._backend.log.recent(),
        )


def _choose_interface(info: ModelInfo, interface: str) -> Interface:
    if interface == "auto":  # co-simulation, else model exchange, else scheduled execution
        return next(i for i in ("cs", "me", "se") if i in info.interfaces)
    if interface not in ("cs", "me", "se"):
        raise ConfigError(f"interface {interface!r} is unknown; expected 'cs', 'me', 'se' or 'auto'")
    if interface not in info.interfaces:
        raise ConfigError(
            f"{info.path.name} has no {interface.upper()} interface; it provides "
            f"{', '.join(i.upper() for i in info.interfaces)} [{info.path}]"
        )
    return interface


def _check_solver(info: ModelInfo, interface: Interface, solver: str, substeps: int) -> tuple[Solver, int]:
    if solver not in SOLVERS:
        raise ConfigError(f"solver {solver!r} is unknown; expected one of {SOLVERS}")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"solver_substeps must be a whole number >= 1, got {substeps!r}")
    if solver != "cvode" and (interface != "me" or info.fmi_major < 2):
        raise ConfigError(
            f"solver {solver!r} integrates FMI 2.0/3.0 model exchange, but {info.path.name} runs "
            f"FMI {info.fmi_version} {interface.upper()}: choose interface 'me' (FMI 2.0/3.0) "
            f"or solver 'cvode'"
        )
    return solver, substeps  # type: ignore[return-value]


def _step_size(info: ModelInfo, step_size_s: float | None) -> float:
    h = step_size_s if step_size_s is not None else info.default_experiment.step_size_s
    if h is None:
        raise ConfigError(
            f"{info.path.name} has no default step size: pass step_size_s (the FMU step size in seconds)"
        )
    if not (math.isfinite(h) and h > 0):
        raise ConfigError(f"step size must be a positive finite number of seconds, got {h!r}")
    return float(h)


@dataclass(frozen=True)
class _Elements:
    """Some elements of an FMI 3.0 array to set at initialisation: ``(flat index, value)``, sorted."""

    items: tuple[tuple[int, Any], ...]


def _whole_array(var: Variable, value: Any) -> list[Any]:
    given: list[Any] = np.asarray(value, dtype=object).reshape(-1).tolist()
    if len(given) != var.size:
        raise VariableError(
            f"{var.name!r} is an array of shape {var.dimensions} ({var.size} elements), got {len(given)} "
            f"values; give all of them, or single elements as {var.element_names()[0]!r}"
        )
    return given


def _by_name(values: Mapping[Variable, Any]) -> dict[str, Any]:
    """Initial values by the names they were given: array elements by their element names."""
    named: dict[str, Any] = {}
    for var, value in values.items():
        if isinstance(value, _Elements):
            names = var.element_names()
            named.update((names[index], x) for index, x in value.items)
        else:
            named[var.name] = value
    return named


def _freeze(values: Mapping[Variable, Any]) -> tuple[Any, ...]:
    return tuple(sorted((v.name, repr(x)) for v, x in values.items()))


def _not_settable_at_init(var: Variable, info: ModelInfo) -> str:
    if var.causality == "structuralParameter":
        return (
            f"{var.name!r} of {info.model_name} is a structural parameter (an array size): it is set in "
            f"configuration mode, once per instance, not at initialisation; give it as "
            f"Model(structural_parameters={{{var.name!r}: ...}}) or under model.structural_parameters "
            f"in the experiment"
        )
    return (
        f"{var.name!r} of {info.model_name} cannot be set: it is a {var.variability} "
        f"{var.causality} (initial={var.initial}); only parameters, inputs and variables with "
        f"initial exact/approx take values at initialisation"
    )


def _not_settable_in_step(var: Variable, info: ModelInfo) -> str:
    if var.settable_at_init:
        return (
            f"{var.name!r} of {info.model_name} is a {var.variability} {var.causality}: it can only be "
            f"set at initialisation; pass it to reset(values) instead"
        )
    return _not_settable_at_init(var, info)
