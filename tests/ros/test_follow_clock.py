"""``fmu-bridge node --follow-clock``: the FMU stepped by another simulator's /clock, published by a
plain-rclpy clock publisher at 1x (ticks finer than the step), 10x (coarser) and with a jump back."""

from __future__ import annotations

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
CARTPOLE = example_experiment("cartpole_balance")
DCMOTOR = example_experiment("dcmotor_tracking")
STEP_NS = 20_000_000  # the experiment's sampling time
CLOCK = "rosgraph_msgs/msg/Clock"


def tick(probe: Probe, clock_ns: int, count: int, **qos: object) -> list[dict[str, object]]:
    """Publish /clock at ``clock_ns`` until ``count`` outputs have come: a tick is idempotent, and
    a best-effort subscription may miss the first samples while discovery completes."""
    for _ in range(30):
        probe.ask(
            "publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": clock_ns}], subscribers=2, **qos
        )
        outputs = probe.ask("wait_count", id="out", count=count, timeout=2)
        if isinstance(outputs, list):
            return outputs
    pytest.fail(f"/clock at {clock_ns} ns did not bring {count} outputs")


def test_fmu_time_follows_the_clock_at_1x_10x_and_back(loopback: Loopback, probe: Probe) -> None:
    args = [
        "node", str(CARTPOLE), "--name", "follower", "--connect", loopback.endpoint,
        "--prefix", loopback.prefix, "--ros-backend", "rclpy", "--follow-clock",
    ]  # fmt: skip
    probe.ask(
        "subscribe", id="out", topic="/follower/outputs", type="sensor_msgs/msg/JointState", keep_all=True
    )
    with command(*args) as node:
        probe.wait(  # ours and rclpy's TimeSource (use_sim_time)
            lambda: len(probe.ask("topic_info", topic="/clock", kind="subscriptions")) >= 2,
            what="/clock subscribers",
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
            if k == 0:  # the first tick, until it is taken (a later one is: discovery is done)
                tick(probe, clock, 1)
            else:
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
        node.wait_for("jumped ahead")  # taken (depth 1: a tick right behind it could replace it)
        probe.ask(
            "publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": last + 300 * 10**9 + STEP_NS}]
        )
        after = probe.ask("wait_count", id="out", count=seen + 1, timeout=30)
        assert isinstance(after, list) and after[-1]["stamp_ns"] == last + 300 * 10**9 + STEP_NS, after[-1]
        assert len(probe.ask("take", id="out", clear=False)) == seen + 1  # one step, not 15,001
        stamps = [m["stamp_ns"] for m in outputs]
        assert stamps.count(250_000_000) == 1 and stamps[0] == 0  # one restart, at the jump back


def follower_args(loopback: Loopback, experiment: object = CARTPOLE) -> list[str]:
    return [
        "node", str(experiment), "--name", "follower", "--connect", loopback.endpoint,
        "--prefix", loopback.prefix, "--ros-backend", "rclpy", "--follow-clock",
    ]  # fmt: skip


def test_a_best_effort_clock_publisher_steps_the_fmu(loopback: Loopback, probe: Probe) -> None:
    """rosbag2's player and Gazebo publish /clock best effort: the node follows it (ROS's clock QoS,
    best effort, depth 1), and says so to the graph."""
    probe.ask(
        "subscribe", id="out", topic="/follower/outputs", type="sensor_msgs/msg/JointState", keep_all=True
    )
    with command(*follower_args(loopback)):
        subscriptions = probe.wait(
            lambda: len(subs := probe.ask("topic_info", topic="/clock", kind="subscriptions")) >= 2 and subs,
            what="two /clock subscriptions",
        )
        # ours and rclpy's own TimeSource (use_sim_time) alike; DDS does not tell the depth
        assert {s["reliability"] for s in subscriptions} == {"best_effort"}, subscriptions
        seen = 0
        for clock in [0, 100_000_000, 200_000_000, 260_000_000]:
            seen = 1 + clock // STEP_NS  # step 0, then one sample per 20 ms step
            outputs = tick(probe, clock, seen, reliability="best_effort")
        assert [m["stamp_ns"] for m in outputs] == [STEP_NS * i for i in range(seen)]


def test_a_forward_jump_is_caught_up_while_the_node_answers_its_services(
    loopback: Loopback, probe: Probe
) -> None:
    """95 s ahead on the DC motor (9,500 steps of 10 ms, under the 10,000 that are caught up; the
    motor never terminates) takes a while to simulate; a ~/reset called right after the jump is
    answered in the middle of it, not after it: the callback of /clock only records the time, the
    steps run beside the services."""
    step_ns, jump_ns = 10_000_000, 95 * 10**9
    probe.ask(
        "subscribe", id="out", topic="/follower/outputs", type="sensor_msgs/msg/JointState", keep_all=True
    )
    with command(*follower_args(loopback, DCMOTOR)) as node:
        probe.wait(
            lambda: probe.ask("topic_info", topic="/clock", kind="subscriptions"), what="/clock subscriber"
        )
        assert probe.ask("client", service="/follower/reset")
        tick(probe, 0, 1)
        probe.ask("publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": jump_ns}])
        answer = probe.ask("trigger", service="/follower/reset", timeout=120)
        assert answer["success"], (answer, node.output)
        outputs = probe.ask("take", id="out", clear=False)
        before = [m for m in outputs if m["t"] < answer["t"] and m["stamp_ns"] > 0]
        print(
            f"reset answered after {answer['elapsed_s'] * 1e3:.1f} ms, {len(before)} of 9500 steps caught up"
        )
        assert len(before) < jump_ns // step_ns, (answer, len(before))
        # the reset ended the catch-up: the FMU never got to the jump's time; the next tick lines
        # the FMU up with the clock again (a new start, stamped with that tick)
        probe.ask("publish", topic="/clock", type=CLOCK, messages=[{"stamp_ns": jump_ns + step_ns}])
        probe.wait(
            lambda: any(m["stamp_ns"] == jump_ns + step_ns for m in probe.ask("take", id="out", clear=False)),
            what="the FMU lined up with the clock after the reset",
        )
        stamps = [m["stamp_ns"] for m in probe.ask("take", id="out")]
        assert jump_ns not in stamps and stamps.count(jump_ns + step_ns) == 1, stamps[-5:]
