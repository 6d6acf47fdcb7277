"""``agent run --managed``: a lifecycle agent node under rclpy, driven by a plain-rclpy lifecycle client
(``~/get_state``, ``~/change_state``), acting on a robot-like JointState publisher."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

from tests.ros.conftest import Probe, command, predicted_forces

pytestmark = [
    pytest.mark.ros,
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(1800),
]  # the balancer trains for minutes
JOINT_STATE = "sensor_msgs/msg/JointState"
NAMES = ["x", "x_dot", "theta", "theta_dot"]


def sample(i: int) -> dict[str, object]:
    return {"stamp_ns": 1_000_000 * (i + 1), "name": NAMES, "position": [0.0, 0.0, 0.01, 0.0]}


def published_within(probe: Probe, key: str, seconds: float) -> list[dict[str, object]]:
    """What arrived on ``key`` in the next ``seconds`` (a check that something does NOT come)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.1)
    return list(probe.ask("take", id=key))


def test_lifecycle_configure_activate_deactivate(balancer: Path, probe: Probe) -> None:
    args = [
        "agent", "run", str(balancer), "--transport", "rclpy", "--managed", "--node", "cart",
        "--missing", "safe", "--safe-value", "0", "--observation-topic", "/robot/joint_states",
        "--action-topic", "/robot/effort", "--timeout", "600",
    ]  # fmt: skip
    # (--timeout: a busy machine's gap between two observations here is no missing observation)
    probe.ask("subscribe", id="act", topic="/robot/effort", type=JOINT_STATE, keep_all=True)
    with command(*args, ready="Ctrl-C stops it") as agent:
        node = "/cart_agent"
        assert probe.ask("lifecycle_get", node=node)["label"] == "unconfigured"
        # unconfigured: no subscription yet, nothing acts
        assert probe.ask("topic_info", topic="/robot/joint_states", kind="subscriptions") == []
        assert probe.ask("lifecycle_change", node=node, transition="configure") == {"success": True}
        assert probe.ask("lifecycle_get", node=node)["label"] == "inactive"
        probe.wait(lambda: probe.ask("topic_info", topic="/robot/joint_states", kind="subscriptions"))
        probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[sample(0)])
        assert published_within(probe, "act", 1.0) == []  # configured but inactive: no action
        assert probe.ask("lifecycle_change", node=node, transition="activate") == {"success": True}
        assert probe.ask("lifecycle_get", node=node)["label"] == "active"
        for i in range(1, 6):
            probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[sample(i)])
            actions = probe.ask("wait_count", id="act", count=i)
            assert isinstance(actions, list), agent.output
        assert all(a["position"][0] in (-10.0, 10.0) for a in actions)
        assert [a["stamp_ns"] for a in actions] == [sample(i)["stamp_ns"] for i in range(1, 6)]
        probe.ask("take", id="act")
        assert probe.ask("lifecycle_change", node=node, transition="deactivate") == {"success": True}
        safe = probe.ask("wait_count", id="act", count=1)
        assert [a["position"] for a in safe] == [[0.0]]  # --missing safe: the safe action, once
        probe.ask("take", id="act")
        probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[sample(9)])
        assert published_within(probe, "act", 1.0) == []  # inactive again: no action
        assert probe.ask("lifecycle_change", node=node, transition="cleanup") == {"success": True}
        assert probe.ask("lifecycle_get", node=node)["label"] == "unconfigured"


def test_configure_fails_on_an_observation_mapping_that_lacks_a_joint(balancer: Path, probe: Probe) -> None:
    """Settings are ROS parameters: the robot's joint names (-p observation_names) lack theta_dot."""
    args = [
        "agent", "run", str(balancer), "--transport", "rclpy", "--managed", "--node", "cart",
        "--ros-args", "-p", "observation_names:=[x, x_dot, theta]", "--",
    ]  # fmt: skip
    with command(*args, ready="Ctrl-C stops it") as agent:
        answer = probe.ask("lifecycle_change", node="/cart_agent", transition="configure")
        assert answer == {"success": False}
        assert probe.ask("lifecycle_get", node="/cart_agent")["label"] == "unconfigured"
        probe.wait(lambda: "observation mapping" in agent.output and "theta_dot" in agent.output)


def test_managed_agent_deploys_the_policy_fmu_set_as_a_parameter(exported_run: Path, probe: Probe) -> None:
    """-p runtime:=fmu: the policy FMU acts as the in-process policy does; cleanup frees it and a
    second configure loads it again; Ctrl-C while active ends the node promptly (well inside 3 s)."""
    args = [
        "agent", "run", str(exported_run), "--transport", "rclpy", "--managed", "--node", "cart",
        "--observation-topic", "/robot/joint_states", "--action-topic", "/robot/effort",
        "--timeout", "30", "--ros-args", "-p", "runtime:=fmu", "--",
    ]  # fmt: skip
    states = np.random.default_rng(5).uniform(-0.15, 0.15, size=(12, 4))
    expected = predicted_forces(exported_run, states)
    probe.ask("subscribe", id="act", topic="/robot/effort", type=JOINT_STATE, keep_all=True)
    with command(*args, ready="Ctrl-C stops it") as agent:
        node = "/cart_agent"
        for round_ in range(2):  # configure, act, clean up; then once more, left active
            assert probe.ask("lifecycle_change", node=node, transition="configure") == {"success": True}
            assert probe.ask("lifecycle_change", node=node, transition="activate") == {"success": True}
            probe.wait(lambda: probe.ask("topic_info", topic="/robot/joint_states", kind="subscriptions"))
            probe.ask("take", id="act")
            for i, state in enumerate(states):
                message = {"stamp_ns": 1_000_000 * (i + 1), "name": NAMES, "position": state.tolist()}
                probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[message])
                actions = probe.ask("wait_count", id="act", count=i + 1)
                assert isinstance(actions, list), agent.output
            assert [a["position"][0] for a in actions] == expected
            if round_ == 0:
                assert probe.ask("lifecycle_change", node=node, transition="deactivate") == {"success": True}
                assert probe.ask("lifecycle_change", node=node, transition="cleanup") == {"success": True}
        assert " ".join(agent.output.split()).count("configured: fmu policy") == 2
        elapsed = agent.stop(signal.SIGINT)
        assert agent.process.returncode == 0 and elapsed < 3.0, (elapsed, agent.output)  # room for load
        assert "Traceback" not in agent.output, agent.output
    assert len(set(expected)) == 2  # both levels: an agent stuck on one force would fail
