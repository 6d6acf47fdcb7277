"""A step watchdog: notices a plant call that has not returned within its deadline.

The node marks the start and end of every reset and step (two attribute writes, nothing per
step beyond that); a daemon thread looks a few times a second and calls ``on_hung`` once when a
call outlives ``deadline_s``. A native call that never returns cannot be interrupted from
Python: the node reports itself unhealthy and, on SIGTERM or Ctrl-C, exits without waiting
for it. Run untrusted FMUs with ``--isolate`` to have the node kill and restart them instead.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

_log = logging.getLogger(__name__)


class Watchdog:
    """Calls ``on_hung(what, elapsed_s)`` once when a call marked by ``begin`` outlives ``deadline_s``."""

    def __init__(
        self, deadline_s: float, on_hung: Callable[[str, float], None], *, name: str = "", watch: bool = True
    ) -> None:
        self.deadline_s = deadline_s
        self.fired = False
        self._on_hung = on_hung
        self._busy: tuple[str, tuple[object, ...], float] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if watch:  # False: the calls are bounded elsewhere (an isolated plant's own deadline)
            self._thread = threading.Thread(target=self._run, name=f"watchdog-{name}", daemon=True)
            self._thread.start()

    @property
    def watching(self) -> bool:
        """Whether a thread looks for overdue calls (not for an isolated plant)."""
        return self._thread is not None and self._thread.is_alive()

    def begin(self, what: str, *args: object) -> None:
        """A call starts; ``what % args`` names it in the report (formatted only if it is late)."""
        self._busy = (what, args, time.monotonic())

    def end(self) -> None:
        self._busy = None

    def busy(self) -> tuple[str, float] | None:
        """The call in progress and for how long, in seconds (None: none); from any thread."""
        busy = self._busy
        if busy is None:
            return None
        what, args, start = busy
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
            what, args, start = busy
            elapsed = time.monotonic() - start
            if elapsed > self.deadline_s:
                self.fired = True
                try:
                    self._on_hung(what % args if args else what, elapsed)
                except Exception:  # the watchdog must outlive whatever it reports
                    _log.exception("the hung-call handler failed")

    def stop(self) -> None:
        self._stop.set()
