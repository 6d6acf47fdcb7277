"""``RealtimeDriver``: calls a node's step on a wall clock, in a thread of its own.

The node knows nothing of threads or clocks in real time: it gives the driver a ``tick``
callable (one sample with the latest action held) and the driver calls it every ``period_s``
seconds on absolute deadlines (``t0 + k * period``, so errors do not add up), as fast as
possible when the period is 0.

Pacing is a hybrid: the thread sleeps until ``spin_s`` before the deadline (an OS sleep wakes
up to tens of microseconds late, and much later on a loaded machine) and then waits out the
rest in a short loop that reads the clock and yields the GIL between reads. The tail costs a
little CPU per period (``spin_s`` at most) and is what brings the period's deviation from
sleep-grade (hundreds of microseconds) to clock-read grade. Where the process may, the thread
asks for ``SCHED_FIFO`` (``realtime_priority``): the kernel then wakes it ahead of ordinary
work; without the privilege it runs as before and says so once in the log.

A tick that ends later than a whole period after its deadline is an overrun: counted, logged
now and then, and the schedule restarts from now (no burst of catch-up ticks).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

_log = logging.getLogger(__name__)
SPIN_S = 300e-6  # the busy tail before each deadline


@dataclass(frozen=True)
class Pacing:
    """How a real-time node keeps its period: ``spin_s`` of busy tail before each deadline (0:
    sleep only), and SCHED_FIFO at ``priority`` (1-99) where the process may (None: never ask)."""

    spin_s: float = SPIN_S
    priority: int | None = None


class RealtimeDriver:
    """Runs ``tick()`` every ``period_s`` seconds until :meth:`stop`.

    Args:
        tick: one sample; returns whether there is anything to step (False: the episode is over,
            so with period 0 the driver idles instead of spinning).
        period_s: seconds between ticks (0: as fast as possible).
        counters: where overruns and internal errors are counted (the node's counters).
        pacing: the busy tail and the scheduling policy (:class:`Pacing`).
    """

    def __init__(
        self,
        tick: Callable[[], bool],
        period_s: float,
        *,
        name: str,
        counters: Counter[str],
        pacing: Pacing | None = None,
    ) -> None:
        self._tick, self.period_s, self.name = tick, period_s, name
        self.counters = counters
        pacing = pacing or Pacing()
        self.spin_s, self.realtime_priority = pacing.spin_s, pacing.priority
        self.scheduling = "normal"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"realtime-{name}", daemon=True)
        self._next = 0.0

    def start(self) -> None:
        self._thread.start()

    def restart_clock(self) -> None:
        """The next tick one period from now (after a reset)."""
        self._next = time.monotonic()

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=timeout_s)

    def _run(self) -> None:
        self._ask_priority()
        self._next = time.monotonic()
        while not self._stop.is_set():
            busy = True
            try:
                busy = self._tick()
            except Exception:  # the stepping thread must outlive anything: count, log, go on
                self.counters["internal_errors"] += 1
                _log.exception("node %s: a real-time step could not be handled", self.name)
                self._stop.wait(0.1)
            self._pace(busy)

    def _pace(self, busy: bool) -> None:
        period = self.period_s
        if period <= 0:
            if not busy:
                self._stop.wait(0.01)
            return
        self._next += period
        now = time.monotonic()
        late = now - self._next
        if late > period:
            self._overrun(late)
            self._next = now
            return
        sleep = -late - self.spin_s
        if sleep > 0 and self._stop.wait(sleep):
            return
        deadline = self._next
        while time.monotonic() < deadline:  # the tail: clock reads, the GIL yielded in between
            time.sleep(0)

    def _overrun(self, late: float) -> None:
        self.counters["overruns"] += 1
        n = self.counters["overruns"]
        if n <= 5 or n % 100 == 0:
            _log.warning("node %s: real-time overrun by %.1f ms (%d so far)", self.name, late * 1e3, n)

    def _ask_priority(self) -> None:
        priority = self.realtime_priority
        if priority is None:
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as exc:
            _log.warning(
                "node %s: SCHED_FIFO %d is not allowed here (%s); running with normal scheduling",
                self.name,
                priority,
                exc,
            )
            return
        self.scheduling = f"SCHED_FIFO {priority}"
