"""A real-time node's deadlines: what its driver's thread does at each one.

At each deadline the sample due now, stepped in the period before, goes out first (its frame,
the ROS view and the clock), so that how long the FMU takes, and how much that varies, never
shifts the frames a subscriber sees. Then the next sample is stepped with the latest action held
over it (zero-order hold from this deadline on) and kept until the next deadline. The first
deadline after a reset has nothing kept: it steps and publishes at once, then steps the next.
A reset drops a kept sample (:meth:`RealtimeStepping.drop`).

The node (``bridge.net.node``) steps and publishes; :class:`~bridge.net.realtime.RealtimeDriver`
owns the thread and the clock; this module holds the kept sample and the order of one deadline.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from bridge.net.realtime import Pacing, RealtimeDriver

Sample = tuple[bytes, int, list[float], bool]  # a stepped frame, its time in ns, values, ended


class RealtimeStepping:
    """Steps a node on its driver's deadlines, each sample published at the deadline after it.

    Args:
        step: one sample with the latest action held, called with ``lock`` held; None when the
            step failed (the node has then answered with an ERROR frame).
        publish: sends a sample's frame, time and values (the outputs and the ROS view).
        clock: the node's clock publisher.
        ended: whether the node's episode is over.
        lock: the node's FMU lock (no step or reset beside a deadline).
        period_s, name, counters, pacing: the driver's (:class:`RealtimeDriver`).
    """

    def __init__(
        self,
        step: Callable[[], Sample | None],
        publish: Callable[[bytes, int, list[float]], None],
        *,
        clock: Any,
        ended: Callable[[], bool],
        lock: threading.Lock,
        period_s: float,
        name: str,
        counters: Counter[str],
        pacing: Pacing | None = None,
    ) -> None:
        self._step, self._publish, self._clock, self._ended, self._lock = step, publish, clock, ended, lock
        self.kept: Sample | None = None
        self.driver = RealtimeDriver(self.tick, period_s, name=name, counters=counters, pacing=pacing)

    def drop(self) -> None:
        """A reset begins (under the node's lock): no sample of the last episode goes out."""
        self.kept = None

    def tick(self) -> bool:
        """One deadline; False when the episode is over and nothing was left to publish."""
        if not self._lock.acquire(timeout=0.5):
            return True
        try:
            kept, self.kept = self.kept, None
            if kept is None and not self._ended():
                kept = self._step()  # the first deadline after a reset
            if kept is not None:
                frame, time_ns, values, ended = kept
                self._publish(frame, time_ns, values)
                if not ended:
                    self._clock.put(np.int64(time_ns).tobytes())
            if self._ended():
                return kept is not None
            self.kept = self._step()  # zero-order hold of the latest action
            return True
        finally:
            self._lock.release()
