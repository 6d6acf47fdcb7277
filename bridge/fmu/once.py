"""FMUs that declare ``canBeInstantiatedOnlyOncePerProcess``: at most one live instance per process.

Such an FMU keeps state in its library's globals (common in Dymola exports), so a second instance in
the same process would share and corrupt the first one's state without any error. Every in-process
instance is a :class:`bridge.fmu.Model`; it claims its FMU here when it opens and gives it back when
it closes (or is collected), and a second claim is refused with the reason and the ways out: each
instance in its own process (an isolated plant, a node, one env per Ray env runner).
"""

from __future__ import annotations

import threading
import weakref
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.fmu.vocab import ModelInfo

_LOCK = threading.Lock()
_LIVE: dict[Path, weakref.ref[Any]] = {}

HOW_TO_ISOLATE = (
    "Run each instance in its own process: FmuEnv and the vector envs over it do so by themselves "
    "(an isolated plant), a batch env needs n_envs=1 per process (one per Ray env runner), a system "
    "needs the FMU once or as a node's component (`fmu-bridge node`)"
)


def claim(info: ModelInfo, owner: object) -> None:
    """Register ``owner`` as the process's instance of ``info``'s FMU if it is once-per-process."""
    if not info.once_per_process:
        return
    key = info.path
    with _LOCK:
        ref = _LIVE.get(key)
        holder = ref() if ref is not None else None
        if holder is not None and not getattr(holder, "closed", False):
            raise ConfigError(
                f"{info.model_name} declares canBeInstantiatedOnlyOncePerProcess and an instance of it is "
                f"already open in this process: a second one would share its global state. "
                f"{HOW_TO_ISOLATE} [{info.path}]"
            )
        _LIVE[key] = weakref.ref(owner)


def release(info: ModelInfo, owner: object) -> None:
    """Give ``info``'s FMU back (a no-op unless ``owner`` holds it)."""
    if not info.once_per_process:
        return
    with _LOCK:
        ref = _LIVE.get(info.path)
        if ref is not None and ref() in (owner, None):
            del _LIVE[info.path]
