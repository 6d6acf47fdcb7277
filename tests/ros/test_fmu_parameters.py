"""The FMU's parameters as ROS parameters of its node, set the way ``ros2 param set`` sets them (the
node's parameter services) from a separate plain-rclpy process: declared with the model
description's range, refused inside an episode with the reason, applied at the next ``~/reset``."""

from __future__ import annotations

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
DCMOTOR = example_experiment("dcmotor_tracking")  # R and J randomised: a reset may set them
JOINT_STATE = "sensor_msgs/msg/JointState"
NODE = "/plant"


def episode(probe: Probe, volts: float, n: int) -> list[float]:
    """~/reset, then ``n`` lockstep actions; the currents of the samples after step 0."""
    probe.ask("take", id="out")
    assert probe.ask("trigger", service="/plant/reset")["success"]
    messages = [{"stamp_ns": k, "name": ["voltage"], "position": [volts]} for k in range(n)]
    probe.ask("publish", topic="/plant/actions", type=JOINT_STATE, messages=messages, keep_all=True)
    outputs = probe.ask("wait_count", id="out", count=n + 1, timeout=120)
    assert isinstance(outputs, list), outputs
    current = outputs[0]["name"].index("current")
    return [m["position"][current] for m in outputs[1 : n + 1]]


def test_fmu_parameter_set_between_episodes_applies_at_the_next_reset(
    loopback: Loopback, probe: Probe
) -> None:
    args = [
        "node", str(DCMOTOR), "--name", "plant", "--connect", loopback.endpoint,
        "--prefix", loopback.prefix, "--ros-backend", "rclpy",
    ]  # fmt: skip
    probe.ask("subscribe", id="out", topic="/plant/outputs", type=JOINT_STATE, keep_all=True)
    with command(*args) as node:
        described = probe.ask("param_describe", node=NODE, name="R")
        assert described["ranges"][0][0] == 0.0 and "next ~/reset" in described["description"]
        assert probe.ask("param_get", node=NODE, name="R") == 1.0  # the FMU's start value
        # below the model description's min: rclpy refuses it against the declared range
        assert not probe.ask("param_set", node=NODE, name="R", value=-1.0)["successful"]
        nominal = episode(probe, 12.0, 300)  # a whole episode (3 s at 10 ms): it has ended
        answer = probe.ask("param_set", node=NODE, name="R", value=4.0)  # between episodes
        assert answer == {"successful": True, "reason": ""}, node.output
        assert probe.ask("param_get", node=NODE, name="R") == 4.0
        resistive = episode(probe, 12.0, 5)  # applied at this reset; the episode goes on
        refused = probe.ask("param_set", node=NODE, name="R", value=1.0)
        assert not refused["successful"] and "inside episode 2 (step 5)" in refused["reason"], refused
        assert probe.ask("param_get", node=NODE, name="R") == 4.0
    # 12 V into the armature: the current rises towards V/R, so four times R gives a smaller one
    assert all(r < n for r, n in zip(resistive, nominal[:5])), (resistive, nominal[:5])
    assert resistive[-1] < 0.5 * nominal[4], (resistive, nominal[:5])
