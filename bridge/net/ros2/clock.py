"""Following an external ``/clock``: ``fmu-bridge node --follow-clock``.

Another simulator (Gazebo, Isaac Sim, a bag being played with ``--clock``) owns time; the FMU
node is a ``use_sim_time`` participant that steps its FMU so that the FMU's time keeps up with the
clock. ``/clock`` is subscribed with ROS's own clock QoS (best effort, depth 1, as rclpy's
``TimeSource`` and rclcpp subscribe it), so rosbag2's player and Gazebo, which publish it best
effort, drive the node as well as a reliable publisher does. The policy:

- **First tick**: the FMU is reset to its start (the experiment's nominal values) and its start
  time is lined up with the clock's time at that tick (the *origin*): the FMU's time ``t`` is
  clock time ``origin + t - t0``, and the outputs are stamped in clock time.
- **Ticks coarser than the node's step** (10x a 20 ms step, say): the node steps as many times as
  fit, publishing each sample, so that the FMU's time comes to within one step of the clock's
  (``clock - step < fmu <= clock``).
- **Ticks finer than the step**: no step until the clock reaches the next step boundary: the FMU
  never runs ahead of the clock.
- **A jump backwards** (the simulator was reset, a bag looped): the FMU is reset to its start and
  lined up with the clock again (a new episode); counted in ``jumps_back``.
- **A jump forwards by more than** ``max_catch_up`` steps: the FMU does not try to simulate the
  gap; it is lined up with the clock again where it is (counted in ``skipped``).
- **An ended episode** (the FMU terminated or failed): no more steps until a reset (``~/reset``
  or a jump back).
- **Paused** (a managed node that is not active): ticks are only recorded, nothing steps or
  resets; :meth:`ClockFollower.resume` lines the FMU up with the clock again at the next tick.

Catching up is bounded per callback: a ``/clock`` callback only records the clock's time (and
lines the FMU up: one reset at most); the steps that are due run on the follower's own thread,
one at a time with the lock released in between, so that actions, resets and the next ticks are
served while the FMU catches up after a forward jump (a 30 s jump is 1,500 steps of 20 ms: the
node answers its services meanwhile instead of after them).

The node's step is its sampling time (``model.sampling_time``), one or more FMU steps.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

_log = logging.getLogger(__name__)
TOLERANCE_NS = 1_000  # rounding of FMU times to ns: a step due at exactly the clock's time is taken


class ClockFollower:
    """Steps a plant on clock ticks, on a thread of its own; ``close()`` stops it.

    Args:
        step_ns: the node's step (sampling time) in ns.
        start: resets the plant to its start; returns its time in ns.
        step: one step with the held inputs; returns the new time in ns, or ``None`` when the
            episode has ended (terminated or failed).
        max_catch_up: the most steps a forward jump may leave to simulate; a longer jump is
            lined up instead.
    """

    def __init__(
        self,
        step_ns: int,
        start: Callable[[], int],
        step: Callable[[], int | None],
        *,
        max_catch_up: int = 10_000,
        name: str = "clock",
    ) -> None:
        if step_ns <= 0:
            raise ValueError(f"step_ns must be > 0, got {step_ns}")
        self.step_ns, self._start, self._step = step_ns, start, step
        self.max_catch_up = max_catch_up
        self.origin_ns: int | None = None  # clock time of the FMU's start
        self.fmu_ns = 0  # the FMU's time
        self.t0_ns = 0
        self.last_clock_ns: int | None = None
        self.ended = False
        self.paused = False
        self.ticks = self.steps = self.jumps_back = self.skipped = 0
        self._lock = threading.Lock()
        self._due_or_closed = threading.Condition(self._lock)
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"follow-{name}", daemon=True)
        self._thread.start()

    @property
    def fmu_clock_ns(self) -> int:
        """The FMU's time on the clock's scale."""
        return (self.origin_ns or 0) + self.fmu_ns - self.t0_ns

    @property
    def behind(self) -> int:
        """Steps due now and not yet taken."""
        with self._lock:
            return self._due()

    def restart(self) -> None:
        """The plant was reset from elsewhere (``~/reset``): line it up again at the next tick."""
        with self._lock:
            self.origin_ns = None

    def pause(self) -> None:
        """Take no step and no reset from now on (ticks are still recorded)."""
        with self._lock:
            self.paused = True

    def resume(self) -> None:
        """Follow the clock again: lined up with it at the next tick (a new episode)."""
        with self._lock:
            self.paused, self.origin_ns = False, None

    def tick(self, clock_ns: int) -> None:
        """A ``/clock`` message: record it (and line up at a start or a jump); never steps."""
        with self._lock:
            self.ticks += 1
            last, self.last_clock_ns = self.last_clock_ns, clock_ns
            if self.paused:
                return
            if self.origin_ns is None or (last is not None and clock_ns < last):
                if self.origin_ns is not None:
                    self.jumps_back += 1
                    _log.warning(
                        "/clock jumped back from %.3f s to %.3f s: the FMU starts again",
                        (last or 0) / 1e9,
                        clock_ns / 1e9,
                    )
                self._line_up(clock_ns)
                return
            due = self._due()
            if due > self.max_catch_up:
                self.skipped += 1
                _log.warning(
                    "/clock jumped ahead by %.3f s (%d steps, at most %d are caught up): the FMU is "
                    "lined up with the clock where it is",
                    (clock_ns - self.fmu_clock_ns) / 1e9,
                    due,
                    self.max_catch_up,
                )
                self.origin_ns = clock_ns - (self.fmu_ns - self.t0_ns)
                return
            if due > 0:
                self._due_or_closed.notify()

    def _due(self) -> int:
        if self.origin_ns is None or self.ended or self.paused or self.last_clock_ns is None:
            return 0
        return max((self.last_clock_ns - self.fmu_clock_ns + TOLERANCE_NS) // self.step_ns, 0)

    def _line_up(self, clock_ns: int) -> None:
        self.origin_ns = clock_ns  # first: step 0, published by the reset, is stamped in clock time
        self.t0_ns = self.fmu_ns = self._start()
        self.ended = False

    def _run(self) -> None:
        while self._one_step():
            time.sleep(0)  # the lock is free: let a tick, an action or a reset in before the next step

    def _one_step(self) -> bool:
        """Wait for a step that is due and take it; False once closed."""
        with self._lock:
            while not self._closed and self._due() <= 0:
                self._due_or_closed.wait()
            if self._closed:
                return False
            try:
                now = self._step()
            except Exception:  # the thread outlives a failed step: no more steps this episode
                _log.exception("/clock: a step could not be taken; waiting for a reset")
                now = None
            if now is None:
                self.ended = True
            else:
                self.fmu_ns = now
                self.steps += 1
            return True

    def close(self, timeout_s: float = 1.0) -> None:
        """Stop stepping (a step under way ends first)."""
        with self._lock:
            self._closed = True
            self._due_or_closed.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=timeout_s)
