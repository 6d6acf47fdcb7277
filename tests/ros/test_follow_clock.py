"""``fmu-bridge node --follow-clock``: the FMU stepped by another simulator's /clock, published by a
plain-rclpy clock publisher at 1x (ticks finer than the step), 10x (coarser) and with a jump back."""

from __future__ import annotations

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
CARTPOLE = example_experiment("cartpole_balance")
STEP_NS = 20_000_000  # the experiment's sampling time
CLOCK = "rosgraph_msgs/msg/Clock"


def test_fmu_time_follows_the_clock_at_1x_10x_and_back(loopback: Loopback, probe: Probe) -> None:
    args = [
        "node", str(CARTPOLE), "--name", "follower", "--connect", loopback.endpoint,
        "--prefix", loopback.prefix, "--ros-backend", "rclpy", "--follow-clock",
    ]  # fmt: skip
    probe.ask(
        "subscribe", id="out", topic="/follower/outputs", type="sensor_msgs/msg/JointState", keep_all=True
    )
    with command(*args) as node:
        probe.wait(
            lambda: probe.ask("topic_info", topic="/clock", kind="subscriptions"), what="/clock subscriber"
        )
        assert probe.ask("topic_info", topic="/clock") == []  # it follows the clock, it does not publish one
        # 1x: 10 ms ticks (finer than the 20 ms step) for 0.4 s; 10x: 100 ms ticks (five steps each)
        # for 1 s; then back to 0.25 s (a reset of the other simulator), and on at 10x
        ticks = [10_000_000 * i for i in range(41)]
        ticks += [ticks[-1] + 100_000_000 * i for i in range(1, 11)]
        ticks += [250_000_000 + 100_000_000 * i for i in range(6)]
        seen = origin = previous_steps = 0
        for k, clock in enumerate(ticks):
            restart = k == 0 or clock < ticks[k - 1]
            if restart:
                origin, previous_steps = clock, 0  # the FMU starts again, lined up with the clock
            expected_steps = (clock - origin) // STEP_NS
            probe.ask("publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": clock}])
            # each tick: step 0 at a (re)start, then one sample per step due; none early, none late
            seen += (1 if restart else 0) + expected_steps - previous_steps
            outputs = probe.ask("wait_count", id="out", count=seen, timeout=30)
            assert isinstance(outputs, list), (clock, outputs, node.output)
            fmu = outputs[-1]["stamp_ns"]  # the FMU's time on the clock's scale
            assert clock - STEP_NS < fmu <= clock, (k, clock, fmu)
            assert fmu == origin + expected_steps * STEP_NS
            previous_steps = expected_steps
        assert len(probe.ask("take", id="out", clear=False)) == seen  # nothing more: no step ran ahead
        # 300 s ahead (15,000 steps, over the 10,000 one tick may take): lined up, not simulated
        last = ticks[-1]
        probe.ask("publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": last + 300 * 10**9}])
        probe.ask(
            "publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": last + 300 * 10**9 + STEP_NS}]
        )
        after = probe.ask("wait_count", id="out", count=seen + 1, timeout=30)
        assert isinstance(after, list) and after[-1]["stamp_ns"] == last + 300 * 10**9 + STEP_NS, after[-1]
        assert len(probe.ask("take", id="out", clear=False)) == seen + 1  # one step, not 15,001
        stamps = [m["stamp_ns"] for m in outputs]
        assert stamps.count(250_000_000) == 1 and stamps[0] == 0  # one restart, at the jump back
