"""``fmu-bridge agent run --transport rclpy``: a trained PPO agent (torch, ONNX, policy FMU) closing the
loop with an FMU node over DDS, and acting on a robot-like JointState publisher; checked from plain rclpy."""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Command, Probe, command, predicted_forces

pytestmark = [
    pytest.mark.ros,
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(1800),
]  # the balancer trains for minutes
CARTPOLE = example_experiment("cartpole_balance")
JOINT_STATE = "sensor_msgs/msg/JointState"
THETA_LIMIT = 0.20944


def other_domain(domain: int) -> str:
    return str(domain % 100 + 101)


@pytest.mark.parametrize(
    ("runtime", "sig"),
    [("torch", signal.SIGINT), ("onnx", signal.SIGTERM), ("fmu", signal.SIGINT)],
    ids=["torch", "onnx", "fmu"],
)
def test_agent_closes_the_loop_over_dds(  # noqa: PLR0917
    exported_run: Path, loopback: Loopback, probe: Probe, ros_domain: int, runtime: str, sig: int
) -> None:
    """Node ``worker-1`` is served as ``/worker_1``; the agent finds it under the same name, in the
    domain given by --ros-domain (both processes' ROS_DOMAIN_ID says another), with no router."""
    env = {**os.environ, "ROS_DOMAIN_ID": other_domain(ros_domain)}
    domain = str(ros_domain)
    node_cmd = [
        "node", str(CARTPOLE), "--name", "worker-1", "--connect", loopback.endpoint, "--prefix",
        loopback.prefix, "--mode", "realtime", "--ros-backend", "rclpy", "--ros-domain", domain,
    ]  # fmt: skip
    agent_cmd = [
        "agent", "run", str(exported_run), "--transport", "rclpy", "--node", "worker-1",
        "--runtime", runtime, "--ros-domain", domain,
    ]  # fmt: skip
    probe.ask("subscribe", id="out", topic="/worker_1/outputs", type=JOINT_STATE, keep_all=True)
    probe.ask("subscribe", id="act", topic="/worker_1/actions", type=JOINT_STATE, keep_all=True)
    node = Command(node_cmd, env)
    agent: Command | None = None
    try:
        node.wait_for("serving")
        probe.wait(lambda: "/worker_1" in probe.ask("nodes"), what="/worker_1 in the graph")
        agent = Command(agent_cmd, env)
        agent.wait_for("Ctrl-C stops it")
        assert "checkpoint" in agent.output  # it says which model it deploys
        probe.wait(lambda: "/worker_1_agent" in probe.ask("nodes"), what="/worker_1_agent in the graph")
        probe.ask("wait_count", id="act", count=1)
        # the agent acts on what it sees: from a fresh episode the pole stays up for 4 s
        assert probe.ask("trigger", service="/worker_1/reset")["success"]
        probe.ask("take", id="out")
        outputs = probe.ask("wait_count", id="out", count=200, timeout=60)
        assert isinstance(outputs, list), outputs
        theta = np.array([m["position"][2] for m in outputs])
        assert np.all(np.abs(theta) < THETA_LIMIT), theta
        actions = probe.ask("take", id="act")
        assert len(actions) >= 150 and {a["position"][0] for a in actions} <= {-10.0, 10.0}
        elapsed = agent.stop(sig)
        assert agent.process.returncode == 0, agent.output
        assert elapsed < 3.0, f"the agent took {elapsed:.2f} s to exit"  # a few tenths; room for load
        for noise in ("Traceback", "Exception"):
            assert noise not in agent.output, agent.output
        assert "observations" in agent.output  # its closing summary
    finally:
        if agent is not None:
            agent.close()
        node.close()


@pytest.mark.parametrize("runtime", ["torch", "onnx", "fmu"])
def test_agent_observes_a_robot_like_publisher(exported_run: Path, probe: Probe, runtime: str) -> None:
    """--observation-topic: joint states from a robot (other joint order, extra joints, its own
    stamps); each action answers one observation, stamped with it, equal to the in-process
    policy's (model.predict), whichever runtime is deployed."""
    args = [
        "agent", "run", str(exported_run), "--transport", "rclpy", "--observation-topic",
        "/robot/joint_states", "--action-topic", "/robot/effort", "--timeout", "30", "--runtime", runtime,
    ]  # fmt: skip
    probe.ask("subscribe", id="act", topic="/robot/effort", type=JOINT_STATE, keep_all=True)
    rng = np.random.default_rng(3)
    states = rng.uniform(-0.15, 0.15, size=(20, 4))
    names = ["wheel", "theta_dot", "x", "theta", "x_dot"]  # not the agent's order, one extra joint
    messages = [
        {
            "stamp_ns": 1_700_000_000_000_000_000 + i * 20_000_000,
            "name": names,
            "position": [0.5, s[3], s[0], s[2], s[1]],
        }
        for i, s in enumerate(states)
    ]
    with command(*args, ready="Ctrl-C stops it") as agent:
        probe.wait(
            lambda: probe.ask("topic_info", topic="/robot/joint_states", kind="subscriptions"),
            what="the agent's subscription",
        )
        for i, message in enumerate(messages):  # a sensor's pace: the next sample after the action
            probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[message])
            actions = probe.ask("wait_count", id="act", count=i + 1)
            assert isinstance(actions, list), actions
        said = " ".join(agent.output.split())  # rich wraps long lines
        assert f"({runtime})" in said and ("policy FMU export" in said) == (runtime == "fmu"), said
    expected = predicted_forces(exported_run, states)
    by_stamp = {a["stamp_ns"]: a for a in actions}
    assert len(by_stamp) == len(messages)
    for message, force in zip(messages, expected):
        action = by_stamp[message["stamp_ns"]]
        assert action["name"] == ["force"]
        assert action["position"] == [force]
    assert len(set(expected)) == 2  # both levels: an agent stuck on one force would fail


def test_launch_file_defaults_need_no_zenoh_router(balancer: Path, probe: Probe) -> None:
    """The two command lines of launch_scripts/fmu_agent.launch.py with its defaults (rclpy backend,
    no router) close the loop: nothing dials a Zenoh router that is not there."""
    import runpy

    from tests.conftest import free_port

    launch = Path(__file__).resolve().parents[2] / "launch_scripts" / "fmu_agent.launch.py"
    lines = runpy.run_path(str(launch))["commands"](str(balancer), str(CARTPOLE))
    assert not any("--connect" in line for line in lines.values())
    # loopback only in tests: the node's own Zenoh peer listens on 127.0.0.1 instead of scouting
    node_line = [*lines["fmu_node"], "--listen", f"tcp/127.0.0.1:{free_port()}"]
    probe.ask("subscribe", id="act", topic="/plant/actions", type=JOINT_STATE, keep_all=True)
    with command(*node_line), command(*lines["fmu_agent"], ready="Ctrl-C stops it") as agent:
        # ready: subscribed and acting; the first action followed within 0.1 s in every measured run
        actions = probe.ask("wait_count", id="act", count=50, timeout=120)
        assert isinstance(actions, list), agent.output
        said = " ".join(agent.output.split())  # it says what its start-up waits for, and how long it took
        assert "loading it (importing torch takes" in said and re.search(r"ready after \d+\.\d s", said), said


def test_launch_file_with_the_zenoh_backend_closes_the_loop(
    exported_run: Path, loopback: Loopback, ros_domain: int
) -> None:
    """The launch file's command lines with ``backend:=zenoh router:=... runtime:=fmu``: node and
    agent on the rmw_zenoh wire through a router, the policy FMU acting; both stop
    promptly (well inside 3 s)."""
    import runpy

    from rosbags.typesys import Stores, get_typestore

    launch = Path(__file__).resolve().parents[2] / "launch_scripts" / "fmu_agent.launch.py"
    lines = runpy.run_path(str(launch))["commands"](
        str(exported_run), str(CARTPOLE), backend="zenoh", router=loopback.endpoint, runtime="fmu"
    )
    received: list[bytes] = []
    session: Any = loopback.session
    sub = session.declare_subscriber(  # the actions as any rmw_zenoh participant sees them
        f"{ros_domain}/plant/actions/**", lambda sample: received.append(sample.payload.to_bytes())
    )
    try:
        with (
            command(*lines["fmu_node"]) as node,
            command(*lines["fmu_agent"], ready="Ctrl-C stops it") as agent,
        ):
            deadline = time.monotonic() + 60
            while len(received) < 50 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert len(received) >= 50, agent.output
            assert "policy FMU export" in " ".join(agent.output.split())
            for process in (agent, node):
                elapsed = process.stop(signal.SIGTERM)
                assert process.process.returncode == 0 and elapsed < 3.0, (elapsed, process.output)
    finally:
        sub.undeclare()
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    actions = [jazzy.deserialize_cdr(payload, "sensor_msgs/msg/JointState") for payload in received]
    assert all(list(a.name) == ["force"] and a.position.tolist() in ([-10.0], [10.0]) for a in actions)
