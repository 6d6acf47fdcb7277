"""One thin adapter per FMI version over FMPy's loaded library.

The adapters speak FMI (camelCase, value references, status codes) so nothing above
``bridge.fmu`` has to. Set-up calls go through FMPy's checked wrappers; the per-step calls
(get/set/doStep) and the restore of a reset (set FMU state) use the raw ctypes functions FMPy
has already bound, with preallocated arguments, which is what keeps stepping and resetting
cheaper than FMPy's own convenience API. Status codes come from ``bridge.fmu.abi``.
"""

from __future__ import annotations

import ctypes
import logging
import pathlib
from collections.abc import Callable
from typing import Any

import numpy as np
from fmpy import fmi1, fmi2, fmi3

from bridge.errors import FmuError, FmuLoadError
from bridge.fmu import logs
from bridge.fmu.abi import DISCARD, WARNING, status_name
from bridge.fmu.clocks import clock_driver_needed
from bridge.fmu.description import Interface, ModelInfo
from bridge.fmu.events import fmi1_iterate

_log = logging.getLogger(__name__)

# FMI-3 type name -> (FMI 1/2 function suffix, FMI 3 function suffix, ctypes type per version)
_V12 = {
    "Float64": ("Real", ctypes.c_double),
    "Int32": ("Integer", ctypes.c_int),
    "Enumeration": ("Integer", ctypes.c_int),
    "Boolean": ("Boolean", None),  # c_char in 1.0, c_int in 2.0
    "String": ("String", ctypes.c_char_p),
}
_V3 = {
    "Float32": ("Float32", ctypes.c_float),
    "Float64": ("Float64", ctypes.c_double),
    "Int8": ("Int8", ctypes.c_int8),
    "UInt8": ("UInt8", ctypes.c_uint8),
    "Int16": ("Int16", ctypes.c_int16),
    "UInt16": ("UInt16", ctypes.c_uint16),
    "Int32": ("Int32", ctypes.c_int32),
    "UInt32": ("UInt32", ctypes.c_uint32),
    "Int64": ("Int64", ctypes.c_int64),
    "UInt64": ("UInt64", ctypes.c_uint64),
    "Enumeration": ("Int64", ctypes.c_int64),
    "Boolean": ("Boolean", ctypes.c_bool),
    "String": ("String", ctypes.c_char_p),
}


class Backend:
    """Common shape of the FMI 1/2/3 adapters; one instance owns one loaded FMPy object."""

    major: int
    fmu: Any

    def __init__(self, info: ModelInfo, unzip_dir: pathlib.Path, interface: Interface, name: str) -> None:
        self.info = info
        self.interface = interface
        self.instance_name = name
        self.log = logs.LogBuffer(name)
        self.component: Any = None
        self._set_state_fn: Callable[[Any, Any], int] | None = None
        self.fmu = self._load(unzip_dir)
        self.functions: dict[str, Any] = self.fmu._functions

    def _load(self, unzip_dir: pathlib.Path) -> Any:
        raise NotImplementedError

    def _fmpy_kwargs(self, unzip_dir: pathlib.Path) -> dict[str, Any]:
        platform = _platform(self.info.fmi_major)
        library = (
            unzip_dir / "binaries" / platform / (self.info.model_identifiers[self.interface] + _suffix())
        )
        if not library.is_file():
            available = sorted(p.name for p in (unzip_dir / "binaries").glob("*")) or ["none"]
            raise FmuLoadError(
                f"{self.info.path.name} has no binary for this platform ({platform}): it ships "
                f"{', '.join(available)}; re-export it for {platform} or build it from its sources "
                f"(`fmpy compile`) [{self.info.path}]"
            )
        return {
            "guid": self.info.guid,
            "modelIdentifier": self.info.model_identifiers[self.interface],
            "unzipDirectory": str(unzip_dir),
            "instanceName": self.instance_name,
            "libraryPath": str(library),
        }

    # -- typed access -------------------------------------------------------------------------
    def ctype(self, var_type: str) -> Any:
        raise NotImplementedError

    def accessor(self, var_type: str, setter: bool) -> Callable[..., int]:
        raise NotImplementedError

    def fast_accessor(self, var_type: str, setter: bool) -> Callable[..., int]:
        """The get/set function re-bound with a void-pointer prototype.

        Callers pass integer addresses of buffers they keep alive; this skips ctypes' per-call
        pointer type checks, about a third of the cost of a small get/set.
        """
        args: list[Any] = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p]
        if self.major == 3:
            args.append(ctypes.c_size_t)
        fn: Callable[..., int] = rebind(self.accessor(var_type, setter), *args)
        return fn

    def type_key(self, var_type: str) -> str:
        """Variables with the same key share one get/set call (FMI 2 Integer and Enumeration)."""
        return _V3[var_type][0] if self.major == 3 else _V12[var_type][0]

    # -- life cycle (implemented per version) --------------------------------------------------
    _INSTANTIATE = "fmi2Instantiate"  # the FMI function's name, for messages (FMI 1.0: two names)

    def instantiate(self) -> None:
        """Create the instance, logging off; on NULL, try once more with the FMU's logging on.

        An FMU that cannot instantiate often says why only to a logger it was told to use (a
        Python-backed FMU's ``ModuleNotFoundError``, a missing resource file); the second try asks
        for every category so that the error carries what it logged.
        """
        component = self._create(logging_on=False)
        if not component:
            component = self._create(logging_on=True)
            if not component:
                raise FmuError(self._null_message(), log=self.log.recent())
            _log.info("%s: instantiated on the second try, with logging on", self.info.model_name)
            self._debug_logging_off(component)
        self.component = component
        self.fmu.component = component

    def _null_message(self) -> str:
        said = "" if self.log.messages else "; it logged nothing, also with logging on"
        what = self._INSTANTIATE
        if self.major == 1:
            what = "fmiInstantiateModel" if self.interface == "me" else "fmiInstantiateSlave"
        return f"{self.info.model_name}: {what} returned NULL (the FMU refused to start){said}"

    def _create(self, logging_on: bool) -> Any:
        """The FMI instantiate call; the new instance, or None/0 when the FMU returned NULL."""
        raise NotImplementedError

    def _debug_logging_off(self, component: Any) -> None:
        """After a retry with logging on: back to the FMU's quiet default."""

    def enter_initialization(self, start_s: float, stop_s: float | None, tolerance: float | None) -> None:
        raise NotImplementedError

    def exit_initialization(self) -> None:
        raise NotImplementedError

    def reset(self) -> None:
        raise NotImplementedError

    def free_instance(self) -> None:
        raise NotImplementedError

    def do_step(self, t: float, h: float) -> int:
        """One communication step; returns the FMI status (termination is reported as DISCARD)."""
        raise NotImplementedError

    def stepper(self) -> Callable[[float, float], int]:
        """``do_step`` with the FMI function bound once (the per-sample hot path)."""
        return self.do_step

    def terminated_after_discard(self) -> bool:
        return False

    def reports_terminated(self) -> bool:
        """Whether the FMU says now, outside a step, that it has terminated (FMI 2.0 co-simulation's
        fmi2Terminated status; False where there is no such query or the FMU does not answer)."""
        return False

    def get_state(self) -> ctypes.c_void_p:
        raise FmuError(f"{self.info.model_name}: FMI {self.info.fmi_version} cannot get/set FMU states")

    _SET_STATE = ""  # fmi2SetFMUstate / fmi3SetFMUState; FMI 1.0 has none

    def set_state(self, state: ctypes.c_void_p) -> None:
        """The FMU's ``SetFMUstate`` called directly, as the step calls are: a restore is a
        reset's hot path, and FMPy's checked wrapper costs several Python frames."""
        fn = self._set_state_fn
        if fn is None:
            if not self._SET_STATE:
                raise FmuError(
                    f"{self.info.model_name}: FMI {self.info.fmi_version} cannot get/set FMU states"
                )
            fn = rebind(self.functions[self._SET_STATE], ctypes.c_void_p, ctypes.c_void_p)
            self._set_state_fn = fn
        status = fn(self.component, state)
        if status > WARNING:
            raise FmuError(
                f"{self.info.model_name}: {self._SET_STATE} returned {status_name(status)}",
                log=self.log.recent(),
            )

    def free_state(self, state: ctypes.c_void_p) -> None:
        pass

    def unload(self) -> None:
        self.fmu.freeLibrary()
        self.log.close()

    def call(self, what: str, fn: Callable[[], Any]) -> Any:
        """Run a set-up call; FMPy's exceptions become FmuError with the FMU's log attached."""
        try:
            return fn()
        except FmuError:
            raise
        except Exception as exc:
            raise FmuError(f"{self.info.model_name}: {what} failed ({exc})", log=self.log.recent()) from exc


def _platform(fmi_major: int) -> str:
    import fmpy

    # FMI 3.0 names binary folders by platform tuple (x86_64-linux), 1.0/2.0 by linux64.
    return str(fmpy.platform_tuple if fmi_major == 3 else fmpy.platform)


def _suffix() -> str:
    import fmpy

    return str(fmpy.sharedLibraryExtension)


class Fmi1Backend(Backend):
    major = 1

    def _load(self, unzip_dir: pathlib.Path) -> Any:
        self._callbacks = logs.fmi1_callbacks()
        self.initial_events: tuple[bool, float | None] = (False, None)
        cls = fmi1.FMU1Slave if self.interface == "cs" else fmi1.FMU1Model
        return cls(**self._fmpy_kwargs(unzip_dir))

    def ctype(self, var_type: str) -> Any:
        if var_type == "Boolean":
            return ctypes.c_char
        return _V12[var_type][1]

    def accessor(self, var_type: str, setter: bool) -> Callable[..., int]:
        fn = self.functions[f"fmi1{'Set' if setter else 'Get'}{_V12[var_type][0]}"]
        return fn  # type: ignore[no-any-return]

    def _create(self, logging_on: bool) -> Any:
        logging_flag = fmi1.fmi1True if logging_on else fmi1.fmi1False
        name, guid = self.instance_name.encode(), self.info.guid.encode()
        if self.interface == "me":
            return self.call(
                "fmiInstantiateModel",
                lambda: self.fmu.fmi1InstantiateModel(name, guid, self._callbacks, logging_flag),
            )
        location = pathlib.Path(self.fmu.unzipDirectory).as_uri()
        return self.call(
            "fmiInstantiateSlave",
            lambda: self.fmu.fmi1InstantiateSlave(
                name,
                guid,
                location.encode(),
                b"application/x-fmu-sharedlibrary",
                0.0,
                fmi1.fmi1False,
                fmi1.fmi1False,
                self._callbacks,
                logging_flag,
            ),
        )

    def _debug_logging_off(self, component: Any) -> None:
        self.functions["fmi1SetDebugLogging"](component, fmi1.fmi1False)

    def enter_initialization(self, start_s: float, stop_s: float | None, tolerance: float | None) -> None:
        self._init_args = (start_s, stop_s)
        if self.interface == "me":
            self.call("fmiSetTime", lambda: self.fmu.setTime(start_s))

    def exit_initialization(self) -> None:
        start_s, stop_s = self._init_args
        if self.interface == "cs":
            self.call("fmiInitializeSlave", lambda: self.fmu.initialize(tStart=start_s, stopTime=stop_s))
            return
        # fmiInitialize runs the first event iteration; finish it here (FMI 1.0 has no event mode).
        first = self.call("fmiInitialize", self.fmu.initialize)
        self.initial_events = self.call("fmiEventUpdate", lambda: fmi1_iterate(self.fmu, first))

    def reset(self) -> None:
        if self.interface == "me":
            raise FmuError(f"{self.info.model_name}: FMI 1.0 model exchange has no reset; re-instantiate")
        self.call("fmiResetSlave", self.fmu.reset)

    def free_instance(self) -> None:
        if self.component:
            if self.interface == "me":
                self.fmu.fmi1FreeModelInstance(self.component)
            else:
                self.fmu.fmi1FreeSlaveInstance(self.component)
            self.component = None

    def stepper(self) -> Callable[[float, float], int]:
        # FMPy 0.3 declares fmiDoStep as returning a string; re-bind it with the FMI 1.0 prototype.
        fn = rebind(
            self.functions["fmi1DoStep"], ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_char
        )
        backend = self
        return lambda t, h: fn(backend.component, t, h, b"\x01")


class Fmi2Backend(Backend):
    major = 2
    _SET_STATE = "fmi2SetFMUstate"

    def _load(self, unzip_dir: pathlib.Path) -> Any:
        self._callbacks = logs.fmi2_callbacks(self.log)
        cls = fmi2.FMU2Slave if self.interface == "cs" else fmi2.FMU2Model
        return cls(**self._fmpy_kwargs(unzip_dir))

    def ctype(self, var_type: str) -> Any:
        if var_type == "Boolean":
            return ctypes.c_int
        return _V12[var_type][1]

    def accessor(self, var_type: str, setter: bool) -> Callable[..., int]:
        return self.functions[f"fmi2{'Set' if setter else 'Get'}{_V12[var_type][0]}"]  # type: ignore[no-any-return]

    def _create(self, logging_on: bool) -> Any:
        kind = fmi2.fmi2CoSimulation if self.interface == "cs" else fmi2.fmi2ModelExchange
        resources = pathlib.Path(self.fmu.unzipDirectory, "resources").as_uri()
        return self.call(
            "fmi2Instantiate",
            lambda: self.fmu.fmi2Instantiate(
                self.instance_name.encode(),
                kind,
                self.info.guid.encode(),
                resources.encode(),
                ctypes.byref(self._callbacks),
                fmi2.fmi2False,
                fmi2.fmi2True if logging_on else fmi2.fmi2False,
            ),
        )

    def _debug_logging_off(self, component: Any) -> None:
        self.functions["fmi2SetDebugLogging"](component, fmi2.fmi2False, 0, None)

    def enter_initialization(self, start_s: float, stop_s: float | None, tolerance: float | None) -> None:
        self.call(
            "fmi2SetupExperiment",
            lambda: self.fmu.setupExperiment(tolerance=tolerance, startTime=start_s, stopTime=stop_s),
        )
        self.call("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)

    def exit_initialization(self) -> None:
        self.call("fmi2ExitInitializationMode", self.fmu.exitInitializationMode)

    def reset(self) -> None:
        self.call("fmi2Reset", self.fmu.reset)

    def free_instance(self) -> None:
        if self.component:
            self.fmu.fmi2FreeInstance(self.component)
            self.component = None

    def stepper(self) -> Callable[[float, float], int]:
        fn, backend, true = self.functions["fmi2DoStep"], self, fmi2.fmi2True
        return lambda t, h: fn(backend.component, t, h, true)

    def terminated_after_discard(self) -> bool:
        flag = ctypes.c_int(0)
        status = self.functions["fmi2GetBooleanStatus"](
            self.component, fmi2.fmi2Terminated, ctypes.byref(flag)
        )
        return bool(status <= WARNING and flag.value)

    def reports_terminated(self) -> bool:
        if self.functions.get("fmi2GetBooleanStatus") is None or not self.component:
            return False
        return self.terminated_after_discard()

    def get_state(self) -> ctypes.c_void_p:
        state = ctypes.c_void_p()
        self.call("fmi2GetFMUstate", lambda: self.fmu.fmi2GetFMUstate(self.component, ctypes.byref(state)))
        return state

    def free_state(self, state: ctypes.c_void_p) -> None:
        if self.component and state:
            self.fmu.fmi2FreeFMUstate(self.component, ctypes.byref(state))


class Fmi3Backend(Backend):
    major = 3
    _SET_STATE = "fmi3SetFMUState"

    clock_update: Callable[[], None] | None = None  # scheduled execution: fmi3ClockUpdateCallback

    def _load(self, unzip_dir: pathlib.Path) -> Any:
        # co-simulation with clocks: instantiated with eventModeUsed (its clocks tick in event mode)
        self.event_mode = self.interface == "cs" and clock_driver_needed(self.info, self.interface)
        classes = {"cs": fmi3.FMU3Slave, "me": fmi3.FMU3Model, "se": fmi3.FMU3ScheduledExecution}
        fmu = classes[self.interface](**self._fmpy_kwargs(unzip_dir))
        self._event = fmi3.fmi3Boolean()
        self._terminate = fmi3.fmi3Boolean()
        self._early = fmi3.fmi3Boolean()
        self._last_time = fmi3.fmi3Float64()
        self._step_refs = (
            ctypes.byref(self._event),
            ctypes.byref(self._terminate),
            ctypes.byref(self._early),
            ctypes.byref(self._last_time),
        )
        return fmu

    def ctype(self, var_type: str) -> Any:
        return _V3[var_type][1]

    def accessor(self, var_type: str, setter: bool) -> Callable[..., int]:
        return self.functions[f"fmi3{'Set' if setter else 'Get'}{_V3[var_type][0]}"]  # type: ignore[no-any-return]

    _INSTANTIATE = "fmi3Instantiate"

    def _create(self, logging_on: bool) -> Any:
        resources = (str(pathlib.Path(self.fmu.unzipDirectory, "resources")) + "/").encode()
        name, token = self.instance_name.encode(), self.info.guid.encode()
        env = ctypes.c_void_p(self.log.id)
        if self.interface == "cs":
            no_vrs = (fmi3.fmi3ValueReference * 0)()
            self._intermediate = fmi3.fmi3IntermediateUpdateCallback()
            create: Callable[[], Any] = lambda: self.fmu.fmi3InstantiateCoSimulation(  # noqa: E731
                name,
                token,
                resources,
                False,
                logging_on,
                self.event_mode,
                False,
                no_vrs,
                0,
                env,
                logs.V3_LOGGER,
                self._intermediate,
            )
        elif self.interface == "se":
            backend = self
            self._se_callbacks = (
                fmi3.fmi3ClockUpdateCallback(lambda _env: backend.clock_update and backend.clock_update()),
                fmi3.fmi3LockPreemptionCallback(lambda: None),
                fmi3.fmi3UnlockPreemptionCallback(lambda: None),
            )
            create = lambda: self.fmu.fmi3InstantiateScheduledExecution(  # noqa: E731
                name, token, resources, False, logging_on, env, logs.V3_LOGGER, *self._se_callbacks
            )
        else:
            create = lambda: self.fmu.fmi3InstantiateModelExchange(  # noqa: E731
                name, token, resources, False, logging_on, env, logs.V3_LOGGER
            )
        return self.call("fmi3Instantiate", create)

    def _debug_logging_off(self, component: Any) -> None:
        self.functions["fmi3SetDebugLogging"](component, False, 0, None)

    def enter_initialization(self, start_s: float, stop_s: float | None, tolerance: float | None) -> None:
        self.call(
            "fmi3EnterInitializationMode",
            lambda: self.fmu.enterInitializationMode(tolerance=tolerance, startTime=start_s, stopTime=stop_s),
        )

    def exit_initialization(self) -> None:
        self.call("fmi3ExitInitializationMode", self.fmu.exitInitializationMode)

    def reset(self) -> None:
        self.call("fmi3Reset", self.fmu.reset)

    def free_instance(self) -> None:
        if self.component:
            self.fmu.fmi3FreeInstance(self.component)
            self.component = None

    def do_step(self, t: float, h: float) -> int:
        status = int(self.functions["fmi3DoStep"](self.component, t, h, True, *self._step_refs))
        if status <= WARNING and self._terminate.value:
            return DISCARD
        return status

    def terminated_after_discard(self) -> bool:
        return bool(self._terminate.value)

    def event_handling_needed(self) -> bool:
        """After a doStep in event mode: whether the FMU asked for an event at the step's end."""
        return bool(self._event.value)

    def get_state(self) -> ctypes.c_void_p:
        state = ctypes.c_void_p()
        self.call("fmi3GetFMUState", lambda: self.fmu.fmi3GetFMUState(self.component, ctypes.byref(state)))
        return state

    def free_state(self, state: ctypes.c_void_p) -> None:
        if self.component and state:
            self.fmu.fmi3FreeFMUState(self.component, ctypes.byref(state))


def open_backend(info: ModelInfo, unzip_dir: pathlib.Path, interface: Interface, name: str) -> Backend:
    """Load the FMU's library for ``interface`` and return the adapter for its FMI version."""
    cls = {1: Fmi1Backend, 2: Fmi2Backend, 3: Fmi3Backend}.get(info.fmi_major)
    if cls is None:
        raise FmuLoadError(
            f"{info.path.name}: FMI version {info.fmi_version!r} is not supported; expected 1.0, 2.0 or 3.0"
        )
    try:
        return cls(info, unzip_dir, interface, name)
    except FmuError:
        raise
    except Exception as exc:
        raise FmuLoadError(
            f"{info.path.name}: loading the {interface.upper()} binary failed: {exc} [{info.path}]"
        ) from exc


def numpy_dtype(ctype: Any) -> np.dtype[Any]:
    if ctype is ctypes.c_char:
        return np.dtype(np.uint8)
    if ctype is ctypes.c_bool:
        return np.dtype(np.bool_)
    dtype: np.dtype[Any] = np.dtype(ctype)
    return dtype


def rebind(fn: Any, *argtypes: Any) -> Any:
    """A loaded FMI function re-bound with our own prototype (returning an FMI status)."""
    address = ctypes.cast(fn, ctypes.c_void_p).value
    if address is None:
        raise FmuLoadError(f"FMI function {fn!r} has a NULL address")
    return ctypes.CFUNCTYPE(ctypes.c_int, *argtypes)(address)
