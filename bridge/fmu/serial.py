"""The FMI calls that turn an FMU state into bytes and back (FMI 2.0 ``fmi2SerializeFMUstate``,
FMI 3.0 ``fmi3SerializeFMUState``), and the capability check that names the flags."""

from __future__ import annotations

import ctypes
from typing import Final

from bridge.errors import StateFileError
from bridge.fmu.backend import Backend
from bridge.fmu.clock_rules import clock_driver_needed
from bridge.fmu.description import Interface, ModelInfo

_CALLS: Final = {
    2: ("fmi2SerializedFMUstateSize", "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate"),
    3: ("fmi3SerializedFMUStateSize", "fmi3SerializeFMUState", "fmi3DeserializeFMUState"),
}
_FLAGS: Final = {
    2: ("canSerializeFMUstate", "canGetAndSetFMUstate"),
    3: ("canSerializeFMUState", "canGetAndSetFMUState"),
}


def refusal(info: ModelInfo, interface: Interface) -> str | None:
    """Why this FMU cannot save its state to a file, or None when it can."""
    serialize_flag, state_flag = _FLAGS.get(info.fmi_major, ("canSerializeFMUstate", "canGetAndSetFMUstate"))
    if info.fmi_major not in _CALLS:
        return (
            f"{info.model_name} cannot save its state to a file: FMI {info.fmi_version} has no FMU state "
            f"functions (FMI 2.0 and 3.0 FMUs declare {serialize_flag} and {state_flag})"
        )
    raw = info.raw
    element = {"cs": raw.coSimulation, "me": raw.modelExchange}.get(interface) or getattr(
        raw, "scheduledExecution", None
    )
    can_state = bool(getattr(element, "canGetAndSetFMUstate", False))
    can_serialize = bool(getattr(element, "canSerializeFMUstate", False))
    if can_state and can_serialize:
        return _clocks_refusal(info, interface) if clock_driver_needed(info, interface) else None
    return (
        f"{info.model_name} ({interface.upper()}) cannot save its state to a file: its model description "
        f"declares {serialize_flag}={str(can_serialize).lower()} and {state_flag}={str(can_state).lower()}, "
        f"and both must be true; re-export the FMU with state serialisation enabled, or start episodes "
        f"from initialisation (reset_policy auto/restore/reset)"
    )


def _clocks_refusal(info: ModelInfo, interface: Interface) -> str:
    """Clocks that tick here have their next ticks in :mod:`bridge.fmu.clocks`, not in the FMU's
    bytes: a state file could not put them back (an in-memory ``ModelState`` does)."""
    return (
        f"{info.model_name} ({interface.upper()}) cannot save its state to a file: its clocks tick here, "
        f"and a state file holds the FMU's state but not when each clock ticks next (fmu-bridge keeps "
        f"that), so episodes started from it would tick at other times; start episodes from "
        f"initialisation (reset_policy auto/restore/reset)"
    )


def check(info: ModelInfo, interface: Interface) -> None:
    """Raise :class:`StateFileError` naming the capability flags where the FMU cannot serialise."""
    why = refusal(info, interface)
    if why is not None:
        raise StateFileError(f"{why} [{info.path}]")


def serialize(backend: Backend, state: ctypes.c_void_p, max_bytes: int) -> bytes:
    """The FMU's bytes for ``state`` (a handle from get_state), at most ``max_bytes`` of them."""
    size_call, serialize_call, _ = _CALLS[backend.major]
    size = ctypes.c_size_t()
    fmu = backend.fmu
    backend.call(size_call, lambda: getattr(fmu, size_call)(backend.component, state, ctypes.byref(size)))
    if size.value > max_bytes:
        raise StateFileError(
            f"{backend.info.model_name}: its state is {size.value} bytes, more than the {max_bytes} allowed"
        )
    buffer = ctypes.create_string_buffer(size.value)
    byte_pointer = backend.functions[serialize_call].argtypes[2]
    backend.call(
        serialize_call,
        lambda: getattr(fmu, serialize_call)(
            backend.component, state, ctypes.cast(buffer, byte_pointer), size.value
        ),
    )
    return buffer.raw


def deserialize(backend: Backend, data: bytes) -> ctypes.c_void_p:
    """A new FMU state handle from ``data`` (free it with ``backend.free_state``)."""
    _, _, deserialize_call = _CALLS[backend.major]
    buffer = ctypes.create_string_buffer(data, len(data))
    byte_pointer = backend.functions[deserialize_call].argtypes[1]
    state = ctypes.c_void_p()
    backend.call(
        deserialize_call,
        lambda: getattr(backend.fmu, deserialize_call)(
            backend.component, ctypes.cast(buffer, byte_pointer), len(data), ctypes.byref(state)
        ),
    )
    return state
