"""Capture an FMU's own log messages, per instance, so errors can carry them.

FMI 1.0 and 2.0 loggers are variadic C functions; FMPy ships a native proxy that formats the
message and forwards it to a single process-wide Python callback. That callback is ours and
dispatches on the component environment (FMI 2.0) or instance name (FMI 1.0) to the
instance's :class:`LogBuffer`. FMI 3.0 passes a preformatted message and an instance
environment pointer, which we set to the buffer's id.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import threading
from collections import deque
from typing import Any

from fmpy import fmi1, fmi2, fmi3
from fmpy.logging import addLoggerProxy

_log = logging.getLogger("bridge.fmu.model")

_STATUS_NAMES = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
_LEVELS = (logging.DEBUG, logging.WARNING, logging.WARNING, logging.ERROR, logging.CRITICAL, logging.INFO)

_ids = itertools.count(1)
_SINKS: dict[int, LogBuffer] = {}
_NAMES: dict[bytes, LogBuffer] = {}
_LOCK = threading.Lock()


class LogBuffer:
    """The most recent log messages of one FMU instance (bounded), forwarded to ``logging``."""

    def __init__(self, instance_name: str, maxlen: int = 200) -> None:
        self.id = next(_ids)
        self.instance_name = instance_name
        self.messages: deque[str] = deque(maxlen=maxlen)
        self._logger = logging.getLogger(f"bridge.fmu.{instance_name.split('#', maxsplit=1)[0]}")
        with _LOCK:
            _SINKS[self.id] = self
            _NAMES[instance_name.encode()] = self

    def add(self, status: int, category: bytes | None, message: bytes | None) -> None:
        status_name = _STATUS_NAMES[status] if 0 <= status < len(_STATUS_NAMES) else str(status)
        cat = category.decode(errors="replace") if category else ""
        text = message.decode(errors="replace") if message else ""
        line = f"[{status_name}] {cat}: {text}" if cat else f"[{status_name}] {text}"
        self.messages.append(line)
        level = _LEVELS[status] if 0 <= status < len(_LEVELS) else logging.INFO
        if self._logger.isEnabledFor(level):
            self._logger.log(level, "%s: %s", self.instance_name, line)

    def recent(self, n: int = 20) -> list[str]:
        return list(self.messages)[-n:]

    def clear(self) -> None:
        self.messages.clear()

    def close(self) -> None:
        with _LOCK:
            _SINKS.pop(self.id, None)
            _NAMES.pop(self.instance_name.encode(), None)


def _dispatch_v1v2(
    env: Any, instance_name: bytes | None, status: int, category: bytes, message: bytes
) -> None:
    sink = _SINKS.get(env) if env else None
    if sink is None and instance_name:
        sink = _NAMES.get(instance_name)
    if sink is not None:
        sink.add(status, category, message)
    else:
        name = instance_name.decode(errors="replace") if instance_name else "?"
        _log.debug("FMU %s: %s", name, message.decode(errors="replace") if message else "")


def _dispatch_v3(env: Any, status: int, category: bytes, message: bytes) -> None:
    sink = _SINKS.get(env) if env else None
    if sink is not None:
        sink.add(status, category, message)
    else:
        _log.debug("FMU: %s", message.decode(errors="replace") if message else "")


_V2_LOGGER = fmi2.fmi2CallbackLoggerTYPE(_dispatch_v1v2)
_V1_LOGGER = fmi1.fmi1CallbackLoggerTYPE(_dispatch_v1v2)
V3_LOGGER = fmi3.fmi3LogMessageCallback(_dispatch_v3)


def fmi2_callbacks(buffer: LogBuffer) -> fmi2.fmi2CallbackFunctions:
    """A callbacks struct for one FMI 2.0 instance; keep a reference for the instance's lifetime."""
    callbacks = fmi2.fmi2CallbackFunctions()
    callbacks.logger = _V2_LOGGER
    callbacks.allocateMemory = fmi2.fmi2CallbackAllocateMemoryTYPE(fmi2.calloc)
    callbacks.freeMemory = fmi2.fmi2CallbackFreeMemoryTYPE(fmi2.free)
    callbacks.stepFinished = fmi2.fmi2StepFinishedTYPE()
    callbacks.componentEnvironment = buffer.id
    addLoggerProxy(ctypes.byref(callbacks))
    return callbacks


def fmi1_callbacks() -> fmi1.fmi1CallbackFunctions:
    """A callbacks struct for FMI 1.0 (dispatch by instance name: 1.0 has no environment pointer)."""
    callbacks = fmi1.fmi1CallbackFunctions()
    callbacks.logger = _V1_LOGGER
    callbacks.allocateMemory = fmi1.fmi1CallbackAllocateMemoryTYPE(fmi1.calloc)
    callbacks.freeMemory = fmi1.fmi1CallbackFreeMemoryTYPE(fmi1.free)
    callbacks.stepFinished = None
    addLoggerProxy(ctypes.byref(callbacks))
    return callbacks
