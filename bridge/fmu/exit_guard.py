"""An FMU that calls ``exit()`` in this process must not end a trainer silently with code 0.

C's ``exit()`` skips Python's shutdown: no exception, no ``atexit``, nothing logged, and the
status the FMU chose (often 0). :func:`guard_native_exit` registers a C exit handler (a small
native helper, ``bridge/fmu/exit_guard.c``) that is armed while Python runs and disarmed by
Python's own shutdown; armed, it writes what happened to stderr and ends the process with code 70
(or the FMU's own non-zero status). An isolated plant's child does not install it: there the
parent reports the exit code as ``PlantDied``.
"""

from __future__ import annotations

import atexit
import logging
import multiprocessing
import threading

from bridge.errors import BridgeError

_log = logging.getLogger(__name__)
_LOCK = threading.Lock()
_state = {"installed": False}
NOTE = (
    "fmu-bridge: native code (an FMU loaded in this process) called exit() while Python was "
    "running; the process ends with code 70 instead of the status it asked for when that was 0. "
    "Run the FMU isolated (model.isolation, or --isolate) to get a PlantDied with its exit code"
)


def guard_native_exit() -> bool:
    """Install the guard once per process; False where it cannot be (no gcc, not Linux)."""
    with _LOCK:
        if _state["installed"]:
            return True
        if multiprocessing.parent_process() is not None:
            return False  # an isolated plant's child: its parent reports the exit code
        from bridge.fmu import native

        try:
            lib = native.load("exit_guard")
            if lib.exit_guard_install(NOTE.encode()) != 0:
                return False
        except (BridgeError, OSError, AttributeError) as exc:
            _log.debug("exit guard not installed: %s", exc)
            return False
        lib.exit_guard_arm(1)
        atexit.register(lib.exit_guard_arm, 0)  # Python's own shutdown is a normal end
        _state["installed"] = True
        return True
