"""``Model``: one FMU instance with typed variable access, integer-indexed stepping and resets.

Time is an integer: after ``k`` FMU steps of size ``h`` the model is at ``t = t0 + k * h``
(never accumulated). A sample of an agent is ``n`` FMU steps (``advance(n)``). ``k`` lives in one
C ``long long`` (the model's clock) that the native steppers (``bridge.fmu.sample``,
``bridge.fmu.batch``) advance in place, so whoever steps the instance, the model knows its time.

Split by responsibility: the instance's runtime (its FMI calls, clock, step, state, and the one
interface native steppers use) is :class:`~bridge.fmu.instance.Instance`, which ``Model`` extends
with what is set up and decided here: settings, variable access, initialisation, the reset policy
and saved states. Beside it: ``model_values`` (settings and initial values checked and written),
``snapshots`` (what a reset restores, and what ``auto`` trusts), ``exchange`` (model exchange
around the integrator), ``stepping`` (native function addresses, step errors) and
``start_state`` (state files). No module but this one touches a ``Model`` member whose name starts
with ``_`` (tests/fmu/test_model_privates.py).
"""

from __future__ import annotations

import ctypes
import itertools
import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from bridge.errors import FMU_LOG_HEADER, ConfigError, FmuError, VariableError
from bridge.fmu import access, archive, exchange, once, python_backed, serial, start_state, structure
from bridge.fmu import model_values as mv
from bridge.fmu.abi import FATAL, Clock
from bridge.fmu.backend import Backend, open_backend
from bridge.fmu.clocks import ClockDriver, ClockedOutputs, ClockInputs, clock_driver
from bridge.fmu.description import Interface, ModelInfo, Variable, read_model_info, unknown_variable_error
from bridge.fmu.instance import Instance
from bridge.fmu.model_values import SOLVERS
from bridge.fmu.signals import SignalGroup
from bridge.fmu.snapshots import Snapshot, Snapshots
from bridge.fmu.spec import ResetPolicy, Solver
from bridge.fmu.state_file import MAX_STATE_BYTES, StateFile
from bridge.fmu.values import to_c

_log = logging.getLogger(__name__)

RESET_POLICIES: tuple[str, ...] = ("auto", "reset", "restore", "reinstantiate")
_counter = itertools.count(1)
__all__ = ["RESET_POLICIES", "SOLVERS", "Model", "ModelState", "Solver"]


@dataclass
class ModelState:
    """A saved state of one :class:`Model` (``Model.save_state``): the FMU's own state, the step
    index and, for model exchange, the next time event. Free it with ``Model.free_state``."""

    handle: ctypes.c_void_p | None
    step_index: int
    terminated: bool
    next_event_s: float | None
    clocks: tuple[Any, ...] | None = None  # the clock schedule (FMUs with clocks that tick)


class Model(Instance):
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
        self.interface: Interface = mv.choose_interface(self.info, interface)
        self.step_size_s = mv.step_size(self.info, step_size_s)
        de = self.info.default_experiment
        self.start_time_s = float(start_time_s if start_time_s is not None else de.start_time_s or 0.0)
        self.stop_time_s = stop_time_s
        self._requested_tolerance = tolerance
        self.tolerance = tolerance if tolerance is not None else de.tolerance
        if reset_policy not in RESET_POLICIES:
            raise ConfigError(f"reset_policy {reset_policy!r} is unknown; expected one of {RESET_POLICIES}")
        self.reset_policy: ResetPolicy = reset_policy
        self.solver, self.solver_substeps = mv.check_solver(
            self.info, self.interface, solver, solver_substeps
        )
        self.can_restore = self.info.can_get_set_state.get(self.interface, False) and self.info.fmi_major >= 2
        self._clock = Clock(0)
        self.terminated = False
        self.initialized = False
        self._init_failed = False
        self.closed = False
        self.failed_status = 0
        self._me: exchange.Integrator | None = None
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
        self._snapshots = Snapshots(self._backend, self.info.model_name, reset_policy, self.can_restore)
        self._do_step = self._backend.stepper() if self.interface == "cs" else self._backend.do_step
        if self._structural:  # the array sizes decide every signal's layout: configure before any use
            try:
                self._backend.instantiate()
                self._configure()
            except BaseException:
                self.close()
                raise
        self._clocks = self._clock_driver(clock_intervals, clock_schedule)

    def _clock_driver(
        self, intervals: Mapping[str, float] | None, schedule: Mapping[str, Sequence[float]] | None
    ) -> ClockDriver | None:
        try:
            clocks = clock_driver(self._backend, self.info, self.interface, intervals, schedule)
        except BaseException:
            self.close()
            raise
        if clocks is not None:
            clocks.read_values = self._clocked_reader
            self._do_step = clocks.step
        return clocks

    # -- context management -------------------------------------------------------------------
    def __enter__(self) -> Model:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Free the instance, its snapshots and the library; safe to call twice."""
        if self.closed:
            return
        self.closed = True
        was_initialized, self.initialized = self.initialized, False
        self._snapshots.drop()
        if self._start is not None:
            start_state.free(self, self._start)
        self._me = None
        try:
            if was_initialized and self.failed_status < FATAL:
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

    # -- variables ----------------------------------------------------------------------------

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
                raise VariableError(mv.not_settable_in_step(var, self.info))
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
                raise VariableError(mv.not_settable_in_step(var, self.info))
        variables = list(dict.fromkeys(var for var, _ in elements.values()))
        flat = access.merge(self._backend, elements, values, self._to_c, self._where)
        clocks = self._clocks
        if clocks is not None and self.initialized and any(v.variability != "continuous" for v in variables):
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

    def _to_c(self, var: Variable, value: Any) -> Any:
        return to_c(var, value, self.info.model_name, self._backend.major)

    # -- initialisation and reset -------------------------------------------------------------
    def initialize(self, values: Mapping[str, Any] | None = None) -> None:
        """Instantiate (first call) and initialise with parameters and start values ``values``."""
        if self.closed:
            raise FmuError(f"{self.info.model_name}: the model is closed; open a new Model")
        checked = self._checked(values or {})
        if self._backend.component is not None and self.unusable:
            # a failed initialisation leaves the instance half-initialised for good: start afresh
            _log.info("%s: re-instantiating after a failed initialisation", self.info.model_name)
            self._reinstantiate(checked)
        else:
            if self._backend.component is None:
                self._backend.instantiate()
            self._initialize(checked)
        self._snapshots.trust.origin = "fresh"
        self._remember(mv.freeze(checked))

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
        if not self.initialized:
            self.initialize(values)
            return
        checked = self._checked(values) if values else {}
        key = mv.freeze(checked) if checked else ()
        policy, snapshots = self.reset_policy, self._snapshots
        if policy in ("auto", "reset"):
            snapshots.judge_episode(self._clock.value, self.terminated)
        snapshot = snapshots.get(key) if self.failed_status == 0 else None
        if snapshot is not None and self._restored(snapshot):
            return
        trust = snapshots.trust
        fresh = policy == "reinstantiate" or self.failed_status >= FATAL or self.info.fmi_major == 1
        if fresh or (policy == "auto" and not trust.fmi_reset_works):
            self._reinstantiate(checked)
        else:
            fresh = self._fmi_reset(checked)
        trust.origin = "fresh" if fresh or not trust.fmi_reset_works else "fmi_reset"
        self._remember(key)

    def _fmi_reset(self, checked: dict[Variable, Any]) -> bool:
        """fmi reset and initialise; True where the instance had to be made afresh instead."""
        try:
            self._backend.reset()
            self._initialize(checked)
            if self.reset_policy in ("auto", "reset") and self._kept_termination():
                # ``reset`` keeps the user's policy and says why its episodes will end at once
                self._snapshots.distrust_reset(
                    "still reports a terminated run after fmi reset and initialisation"
                )
                if self.reset_policy == "auto":
                    self._reinstantiate(checked)
                    return True
        except FmuError as exc:
            said = str(exc).partition(FMU_LOG_HEADER)[0]  # the log comes with the error, if it stays
            _log.warning("%s: the FMU's reset failed (%s); re-instantiating", self.info.model_name, said)
            self._reinstantiate(checked)
            return True
        return False

    def _kept_termination(self) -> bool:
        trusted = self._snapshots.trust.fmi_reset_works
        return trusted and self.interface == "cs" and self._backend.reports_terminated()

    def _restored(self, snapshot: Snapshot) -> bool:
        """Back to ``snapshot``; False (snapshots dropped) where the FMU refused it under ``auto``
        (some FMUs refuse their state functions once fmi-reset)."""
        state, next_event_s = snapshot
        try:
            self._backend.set_state(state)
        except FmuError as exc:
            if self.reset_policy != "auto":
                raise
            _log.warning("%s: restoring a snapshot failed (%s); re-instantiating", self.info.model_name, exc)
            self._snapshots.drop()
            self._snapshots.trust.fmi_reset_works = False  # the reset left state functions unusable
            return False
        self._clock.value, self.terminated = 0, False  # _restart() inlined: the reset hot path
        if self._me is not None:
            self._me.restart(self.start_time_s)
            self._me.next_event_s = next_event_s
        if self._clocks is not None:
            self._clocks.rewind(self.start_time_s)
        self._snapshots.trust.origin = "restore"
        return True

    def _remember(self, key: tuple[Any, ...]) -> None:
        self._snapshots.remember(key, self._me.next_event_s if self._me is not None else None)

    def _reinstantiate(self, values: dict[Variable, Any]) -> None:
        self._snapshots.drop()
        self._backend.free_instance()
        self._backend.instantiate()
        self._initialize(values)

    def _configure(self) -> None:
        """Structural parameters in configuration mode; the FMU's array sizes into :attr:`info`."""
        info = mv.configure(self._backend, self.info, self._structural, self._to_c, self._where)
        if self._configured and info != self.info:
            raise FmuError(f"{self.info.model_name}: the FMU changed its array sizes on reconfiguration")
        self.info = self._backend.info = info
        self._configured = True

    def _initialize(self, values: dict[Variable, Any]) -> None:
        self.initialized = False
        self._init_failed = True  # until it completes
        self._backend.log.clear()
        if self._structural and not self._fresh_configuration():
            self._configure()  # instantiated or fmi reset: structural parameters are back at their starts
        # FMI 1.0 takes every start value before fmiInitialize; 2.0/3.0 calculated ones in init mode,
        # and array elements there too: the other elements are read first, which FMI 3.0 allows
        # only from initialisation mode on.
        early, late = mv.split_early(values, self._backend.major)
        self._init_values = mv.by_name(values)
        mv.write(self._backend, early, values, self._to_c, self._where)
        # Tolerance steers a co-simulation FMU's own solver; for model exchange it is ours (CVode).
        tolerance = self.tolerance if self.interface == "cs" else None
        self._backend.enter_initialization(self.start_time_s, self.stop_time_s, tolerance)
        mv.write(self._backend, late, values, self._to_c, self._where)
        if self._clocks is not None:
            self._clocks.configure(self.start_time_s)
        self._backend.exit_initialization()
        if self._clocks is not None:  # model exchange: the clocks due at the start, in event mode
            self._clocks.start(self.start_time_s)
        if self.interface == "me":
            self._start_me()
        self.initialized = True
        self._init_failed = False
        self.failed_status = 0
        self._restart()

    def _start_me(self) -> None:
        next_event = exchange.leave_initialization(self._backend, self.info.model_name)
        if self._me is None or self._me.fmu is not self._backend.fmu:
            self._me = self._me_stepper(next_event)
        else:
            self._me.next_event_s = next_event

    def _fresh_configuration(self) -> bool:
        """True once, right after the configuration made when the model was opened."""
        fresh = self._configured and not self._initialized_once
        self._initialized_once = True
        return fresh

    def _me_stepper(self, next_event: float | None) -> exchange.Integrator:
        grid, tolerances = (self.start_time_s, self.step_size_s), (self._requested_tolerance, self.tolerance)
        return exchange.integrator(
            self._backend, self.solver, self.solver_substeps, grid, tolerances, next_event_s=next_event
        )

    def _restart(self) -> None:
        self.step_index = 0
        self.terminated = False
        if self._me is not None:
            self._me.restart(self.start_time_s)

    def _checked(self, values: Mapping[str, Any]) -> dict[Variable, Any]:
        return mv.checked(self.info, values, self._element, self._to_c)

    # -- saved states (rollback) ---------------------------------------------------------------
    def save_state(self) -> ModelState:
        """The state now (FMU state, step index, time); needs ``can_restore`` (FMI 2.0/3.0 FMUs
        with canGetAndSetFMUstate), else :class:`FmuError`. Free it with :meth:`free_state`."""
        if not self.can_restore or not self.initialized:
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
        if state.handle is None or self.closed:
            raise FmuError(f"{self.info.model_name}: cannot restore a freed state or into a closed model")
        self._backend.set_state(state.handle)
        self.step_index, self.terminated = state.step_index, state.terminated
        if self.failed_status < FATAL:
            self.failed_status = 0
        if self._me is not None:
            self._me.restart(self.time_s)
            self._me.next_event_s = state.next_event_s
        if self._clocks is not None and state.clocks is not None:
            self._clocks.load(state.clocks)

    def free_state(self, state: ModelState) -> None:
        """Release ``state``'s memory in the FMU; safe to call twice."""
        if state.handle is not None and not self.closed:
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
                self._snapshots.drop()
            return
        start = start_state.prepare(self, file, source)
        if self._start is not None:
            start.own_start_time_s = self._start.own_start_time_s
            start_state.free(self, self._start)
        self._snapshots.drop()
        self._start = start

    # -- continuous states (model exchange) -----------------------------------------------------
    def continuous_states(self) -> npt.NDArray[np.float64]:
        """The continuous states ``x`` now (model exchange, initialised), in the FMU's order."""
        return exchange.continuous_states(self._backend, self.info, self._me_ready)

    def set_continuous_states(self, x: npt.ArrayLike) -> None:
        """Set the continuous states ``x`` (model exchange, in continuous-time mode)."""
        exchange.set_continuous_states(self._backend, self.info, self._me_ready, x)
        self._inputs_dirty = True

    def derivatives(self) -> npt.NDArray[np.float64]:
        """The state derivatives ``dx/dt`` at the current states and inputs (model exchange)."""
        return exchange.derivatives(self._backend, self.info, self._me_ready)

    @property
    def _me_ready(self) -> bool:
        return self.interface == "me" and self.initialized

    # -- for state-file starts (bridge.fmu.start_state): the instance's own initialisation ----
    @property
    def init_values(self) -> dict[str, Any]:
        """The parameters and start values of the last initialisation, by name (for state files)."""
        return dict(self._init_values)

    def initialize_instance(self, values: Mapping[str, Any]) -> None:
        """Initialise the current instance with ``values``, no snapshot taken: a state is set over it."""
        self._initialize(self._checked(values))

    def entered_state(
        self, start_time_s: float, step_index: int, terminated: bool, next_event_s: float | None
    ) -> None:
        """The instance now holds a state set over it (a state file's): its time grid starts at
        ``start_time_s`` and stands at ``step_index``; model exchange integrates on from there."""
        self.start_time_s = start_time_s
        self.step_index, self.terminated = step_index, terminated
        self.initialized, self._init_failed, self.failed_status = True, False, 0
        if self.interface != "me":
            return
        if self._me is None or self._me.fmu is not self._backend.fmu:
            self._me = self._me_stepper(next_event_s)
        self._me.restart(self.time_s)
        self._me.next_event_s = next_event_s
