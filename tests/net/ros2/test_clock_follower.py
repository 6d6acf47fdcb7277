"""The /clock follower's pause (a managed node that is not active) as a plain unit test: real
threads, no ROS, no network; waits on conditions."""

from __future__ import annotations

import time
from collections.abc import Callable

from bridge.net.ros2.clock import ClockFollower

STEP_NS = 20_000_000  # 20 ms
MS = 1_000_000


def until(condition: Callable[[], bool], what: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} not within {timeout_s} s"
        time.sleep(0.001)


def test_a_paused_follower_neither_steps_nor_resets_and_lines_up_again_on_resume() -> None:
    fmu = {"t": 0, "starts": 0}

    def start() -> int:
        fmu["t"], fmu["starts"] = 0, fmu["starts"] + 1
        return 0

    def step() -> int:
        fmu["t"] += STEP_NS
        return fmu["t"]

    follower = ClockFollower(STEP_NS, start, step, name="test")
    try:
        follower.tick(1_000 * MS)  # the first tick lines the FMU up (a reset)
        follower.tick(1_100 * MS)
        until(lambda: follower.steps == 5, "5 steps")
        follower.pause()
        follower.tick(1_400 * MS)  # 15 steps due, were it active
        follower.tick(900 * MS)  # a jump back: no reset while paused either
        assert (follower.behind, fmu["starts"], follower.jumps_back) == (0, 1, 0)
        assert follower.steps == 5 and fmu["t"] == 100 * MS
        follower.resume()
        follower.tick(2_000 * MS)  # lined up again where the clock is: a new episode
        assert fmu["starts"] == 2 and follower.origin_ns == 2_000 * MS
        follower.tick(2_060 * MS)
        until(lambda: follower.steps == 8, "3 more steps")
        assert fmu["t"] == 60 * MS and follower.fmu_clock_ns == 2_060 * MS
    finally:
        follower.close()
