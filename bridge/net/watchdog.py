"""A step watchdog: notices a plant call that has not returned within its deadline.

The node marks the start and end of every reset and step (two attribute writes, nothing per
step beyond that); a daemon thread looks a few times a second and calls ``on_hung`` once when a
call outlives ``deadline_s``. A native call that never returns cannot be interrupted from
Python: the node reports itself unhealthy and, on SIGTERM or Ctrl-C, exits without waiting
for it. Run untrusted FMUs with ``--isolate`` to have the node kill and restart them instead.

A call may carry its own deadline (``begin(..., deadline_s=...)``); ``math.inf`` watches nothing
but says every 30 s that the call is still running (a model's first initialisation, whose length
nothing has measured yet).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

_log = logging.getLogger(__name__)
STILL_RUNNING_S = 30.0  # how often a call without a deadline is said to be still running


class Watchdog:
    """Calls ``on_hung(what, elapsed_s, deadline_s)`` once when a call marked by ``begin`` outlives its
    deadline (``deadline_s``, or the call's own)."""

    def __init__(
        self,
        deadline_s: float,
        on_hung: Callable[[str, float, float], None],
        *,
        name: str = "",
        watch: bool = True,
    ) -> None:
        self.deadline_s = deadline_s
        self.fired = False
        self._on_hung = on_hung
        self._busy: tuple[str, tuple[object, ...], float, float] | None = None
        self._told = 0  # how many STILL_RUNNING_S periods of the current call were logged
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if watch:  # False: the calls are bounded elsewhere (an isolated plant's own deadline)
            self._thread = threading.Thread(target=self._run, name=f"watchdog-{name}", daemon=True)
            self._thread.start()

    @property
    def watching(self) -> bool:
        """Whether a thread looks for overdue calls (not for an isolated plant)."""
        return self._thread is not None and self._thread.is_alive()

    def begin(self, what: str, *args: object, deadline_s: float | None = None) -> None:
        """A call starts; ``what % args`` names it in the report (formatted only if it is late).
        ``deadline_s``: this call's own (default: the watchdog's; ``math.inf``: none)."""
        self._told = 0
        self._busy = (what, args, time.monotonic(), self.deadline_s if deadline_s is None else deadline_s)

    def end(self) -> None:
        self._busy = None

    def busy(self) -> tuple[str, float] | None:
        """The call in progress and for how long, in seconds (None: none); from any thread."""
        busy = self._busy
        if busy is None:
            return None
        what, args, start, _ = busy
        return (what % args if args else what), time.monotonic() - start

    def rearm(self) -> None:
        """Report the next overdue call too (``on_hung`` is called once until then)."""
        self.fired = False

    def _run(self) -> None:
        period = min(0.25, self.deadline_s / 4)
        while not self._stop.wait(period):
            busy = self._busy
            if busy is None or self.fired:
                continue
            what, args, start, deadline_s = busy
            elapsed = time.monotonic() - start
            if math.isinf(deadline_s):
                if elapsed >= (self._told + 1) * STILL_RUNNING_S:
                    self._told += 1
                    _log.info("%s is still running after %.0f s", what % args if args else what, elapsed)
                continue
            if elapsed > deadline_s:
                self.fired = True
                try:
                    self._on_hung(what % args if args else what, elapsed, deadline_s)
                except Exception:  # the watchdog must outlive whatever it reports
                    _log.exception("the hung-call handler failed")

    def stop(self) -> None:
        self._stop.set()
