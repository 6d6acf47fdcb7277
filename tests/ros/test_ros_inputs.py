"""The FMU node's ROS inputs as a ROS user drives them from plain rclpy: ``~/reset`` starts the next
episode without the last one's action, rejected actions are logged once per cause, and lockstep over
ROS ends an episode at ``model.episode_duration``."""

from __future__ import annotations

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
CARTPOLE = example_experiment("cartpole_balance")
DCMOTOR = example_experiment("dcmotor_tracking")  # 10 ms samples, 3 s episodes, never terminates
JOINT_STATE = "sensor_msgs/msg/JointState"


def node_args(loopback: Loopback, experiment: object, *extra: str) -> list[str]:
    return [
        "node", str(experiment), "--name", "plant", "--connect", loopback.endpoint,
        "--prefix", loopback.prefix, "--ros-backend", "rclpy", *extra,
    ]  # fmt: skip


def action(name: str, value: float, k: int = 0) -> dict[str, object]:
    return {"stamp_ns": k, "name": [name], "position": [value]}


def test_reset_starts_the_next_episode_without_the_held_action(loopback: Loopback, probe: Probe) -> None:
    """Real time: +10 N is held until ~/reset; after it the cart starts from rest with the input's
    start value (0 N), not pushed on by the last episode's force."""
    probe.ask("subscribe", id="out", topic="/plant/outputs", type=JOINT_STATE, keep_all=True)
    with command(*node_args(loopback, CARTPOLE, "--mode", "realtime")) as node:
        probe.ask("publish", topic="/plant/actions", type=JOINT_STATE, messages=[action("force", 10.0)])
        pushed = probe.wait(
            lambda: [m for m in probe.ask("take", id="out", clear=False) if m["position"][1] > 1.0],
            what="the cart pushed by +10 N",
        )
        assert pushed, node.output
        assert probe.ask("trigger", service="/plant/reset")["success"]

        def new_episode() -> list[float]:  # x_dot from the new episode's first sample on
            outputs = probe.ask("take", id="out", clear=False)
            # where simulation time went back (a busy reader may miss step 0 itself: the node's
            # KEEP_LAST publisher drops what a reader has not taken)
            starts = [
                i for i in range(1, len(outputs)) if outputs[i]["stamp_ns"] <= outputs[i - 1]["stamp_ns"]
            ]
            if not starts:
                return []
            x_dot = [m["position"][1] for m in outputs[starts[-1] :]]
            return x_dot if len(x_dot) >= 25 else []

        x_dot = probe.wait(new_episode, timeout_s=60, what="half a second of the new episode")
        assert max(abs(v) for v in x_dot) < 0.5, x_dot  # +10 N held on: 4.5 m/s after 0.5 s


def test_rejected_actions_are_counted_and_logged_once_per_cause(loopback: Loopback, probe: Probe) -> None:
    """NaN, inf and 1e308 (outside the input's declared range) never step the FMU; each cause is
    logged once with its reason, repeats are only counted."""
    probe.ask("subscribe", id="out", topic="/plant/outputs", type=JOINT_STATE, keep_all=True)
    with command(*node_args(loopback, DCMOTOR)) as node:
        assert probe.ask("trigger", service="/plant/reset")["success"]
        bad = [float("nan"), float("inf"), 1e308, float("nan"), -1e308, float("-inf")]
        messages = [action("voltage", v, k) for k, v in enumerate(bad)] + [action("voltage", 1.0, 9)]
        probe.ask("publish", topic="/plant/actions", type=JOINT_STATE, messages=messages, keep_all=True)
        outputs = probe.ask("wait_count", id="out", count=2, timeout=30)
        assert isinstance(outputs, list), node.output
        assert [m["stamp_ns"] for m in outputs] == [0, 10_000_000]  # one step: the valid action
        node.wait_for("ROS action rejected (an input is NaN or infinite")
        node.wait_for("ROS action rejected (input 'voltage' = 1e+308 is outside its declared range")
        said = " ".join(node.output.split())
        assert said.count("ROS action rejected") == 2, node.output


def test_lockstep_over_ros_ends_the_episode_at_its_duration(loopback: Loopback, probe: Probe) -> None:
    """model.episode_duration 3 s at 10 ms: 300 steps; the 301st action is not stepped (and said so)."""
    probe.ask("subscribe", id="out", topic="/plant/outputs", type=JOINT_STATE, keep_all=True)
    with command(*node_args(loopback, DCMOTOR)) as node:
        assert probe.ask("trigger", service="/plant/reset")["success"]
        messages = [action("voltage", 1.0, k) for k in range(310)]
        probe.ask("publish", topic="/plant/actions", type=JOINT_STATE, messages=messages, keep_all=True)
        outputs = probe.ask("wait_count", id="out", count=301, timeout=120)
        assert isinstance(outputs, list), node.output
        node.wait_for("after the end of episode")
        outputs = probe.ask("take", id="out")
        assert len(outputs) == 301 and outputs[-1]["stamp_ns"] == 3 * 10**9, outputs[-3:]
        # a reset starts the next episode, which takes actions again
        assert probe.ask("trigger", service="/plant/reset")["success"]
        probe.ask("publish", topic="/plant/actions", type=JOINT_STATE, messages=[action("voltage", 1.0)])
        assert isinstance(probe.ask("wait_count", id="out", count=2, timeout=30), list), node.output
