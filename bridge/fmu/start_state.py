"""Episodes that start from a saved state instead of initialisation (``Model.start_from``), and
the state of a model as a state file (``Model.state_file``).

A state file's state is deserialised into the instance once and restored at every reset, so a
reset costs one ``SetFMUstate``; the first one needs no initialisation at all where the FMU accepts
a state straight after instantiation (FMI 2.0 and 3.0 allow it; an FMU that refuses to
deserialise or set it then is initialised first, with the saving run's start values). Where the
file was saved on this model's step size, the step index goes on from the saved one, so the
episode's time grid ``t0 + k * h`` is the one the state was saved on, bit for bit; otherwise the
episode starts at the saved time with ``k = 0``.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.errors import FMU_LOG_HEADER, FmuError, StateFileError
from bridge.fmu import serial, state_file
from bridge.fmu.abi import FATAL
from bridge.fmu.state_file import StateFile, StateHeader

if TYPE_CHECKING:
    from bridge.fmu.model import Model, ModelState


@dataclass
class StartState:
    """A state file deserialised into one instance (``component``) of a model."""

    file: StateFile
    source: str
    start_time_s: float
    step_index: int
    own_start_time_s: float  # the model's t0 without the state (a clear goes back to it)
    handle: ctypes.c_void_p | None = None
    component: Any = None


def to_file(model: Model, state: ModelState | None, max_bytes: int) -> StateFile:
    """``state`` (default: the state now) as a state file, with its place on the time grid."""
    serial.check(model.info, model.interface)
    own = state is None
    saved = model.save_state() if state is None else state
    try:
        if saved.handle is None:
            raise FmuError(f"{model.info.model_name}: cannot save a freed state")
        payload = serial.serialize(model.backend, saved.handle, max_bytes)
    finally:
        if own:
            model.free_state(saved)
    info = model.info
    header = StateHeader(
        fmi_version=info.fmi_version,
        model_name=info.model_name,
        model_identifier=info.model_identifiers[model.interface],
        instantiation_token=info.guid,
        interface=model.interface,
        time_s=model.start_time_s + saved.step_index * model.step_size_s,
        start_time_s=model.start_time_s,
        step_size_s=model.step_size_s,
        step_index=saved.step_index,
        terminated=saved.terminated,
        next_event_s=saved.next_event_s,
        size=len(payload),
        sha256="",
        start_values={name: _jsonable(value) for name, value in model.init_values.items()},
    )
    return state_file.seal(header, payload)


def prepare(model: Model, file: StateFile, source: str) -> StartState:
    """Check that ``file`` is this model's and place the model's time grid on it."""
    serial.check(model.info, model.interface)
    header = file.header
    state_file.check_fits(header, model.info, model.interface, source)
    if not math.isfinite(header.time_s):
        raise StateFileError(f"the state's time {header.time_s!r} is not finite [{source}]")
    if header.step_size_s == model.step_size_s:
        return StartState(file, source, header.start_time_s, header.step_index, model.start_time_s)
    return StartState(file, source, header.time_s, 0, model.start_time_s)


def restore(model: Model, start: StartState, values: dict[str, Any]) -> None:
    """Put ``model`` into the saved state (the reset of a state-file episode)."""
    _check_values(start, values)
    backend = model.backend
    if backend.component is not None and (model.unusable or model.failed_status >= FATAL):
        backend.free_instance()
        start.handle = None
    if backend.component is None:
        backend.instantiate()
        start.handle = None
    try:
        _set(backend, start)
    except FmuError as first:
        if model.initialized:
            raise _refused(model, start, first) from first
        # An FMU that reads or sets a state only once initialised (the standard allows both
        # straight after instantiation): initialised with the saving run's start values, then set.
        try:
            model.initialize_instance(start.file.header.start_values)
            _set(backend, start)
        except FmuError as exc:  # the FMU refused the bytes: say so, not what failed after it
            raise _refused(model, start, first) from exc
    header = start.file.header
    model.entered_state(start.start_time_s, start.step_index, header.terminated, header.next_event_s)


def _set(backend: Any, start: StartState) -> None:
    if start.handle is None or start.component is not backend.component:
        start.handle, start.component = serial.deserialize(backend, start.file.payload), backend.component
    backend.set_state(start.handle)


def _refused(model: Model, start: StartState, exc: FmuError) -> FmuError:
    """The FMU refused a state's bytes: the size, whose state it claims to be, and the FMU's words
    (an FMU left broken by the refusal fails whatever comes next, e.g. its setup call)."""
    header = start.file.header
    cause = str(exc).split(FMU_LOG_HEADER)[0]
    return FmuError(
        f"{model.info.model_name} refused the state it was given: its {len(start.file.payload)} bytes "
        f"(saved by {header.model_name} at t = {header.time_s:g} s) are not a state this FMU "
        f"deserialises ({cause}); a state is accepted only from the same FMU build, uncut and "
        f"unchanged [{start.source}]",
        log=exc.log,
    )


def free(model: Model, start: StartState) -> None:
    if start.handle is not None and start.component is model.backend.component:
        model.backend.free_state(start.handle)
    start.handle = None


def _check_values(start: StartState, values: dict[str, Any]) -> None:
    saved = start.file.header.start_values
    differ = sorted(n for n, v in values.items() if n not in saved or saved[n] != _jsonable(v))
    if differ:
        shown = ", ".join(f"{n}={values[n]!r} (saved: {saved.get(n, 'not set')!r})" for n in differ)
        raise StateFileError(
            f"a state file fixes every parameter and start value, but this episode asks for other "
            f"ones: {shown}; save a state with these values, or drop them from the experiment "
            f"[{start.source}]"
        )


def _jsonable(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.hex()
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    return value
