"""``agent run --managed`` as ROS users run it: every way out of active ends with the safe action,
the lifecycle services answer while ``configure`` loads the policy, and the process ends once
``finalized``; driven and watched from a separate plain-rclpy process."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from tests.ros.conftest import Command, Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(900)]
JOINT_STATE = "sensor_msgs/msg/JointState"
NAMES = ["x", "x_dot", "theta", "theta_dot"]
NODE = "/cart_agent"
ARGS = [
    "--transport", "rclpy", "--managed", "--node", "cart", "--observation-topic", "/robot/joint_states",
    "--action-topic", "/robot/effort", "--timeout", "30",
]  # fmt: skip  # missing: hold (the default): leaving active is safe all the same


def activate_and_act(probe: Probe, agent: Command, n: int = 3) -> None:
    assert probe.ask("lifecycle_change", node=NODE, transition="configure") == {"success": True}
    assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
    probe.wait(lambda: probe.ask("topic_info", topic="/robot/joint_states", kind="subscriptions"))
    for i in range(n):
        message = {"stamp_ns": 1_000_000 * (i + 1), "name": NAMES, "position": [0.0, 0.0, 0.01, 0.0]}
        probe.ask("publish", topic="/robot/joint_states", type=JOINT_STATE, messages=[message])
        actions = probe.ask("wait_count", id="act", count=i + 1)
        assert isinstance(actions, list), agent.output
    assert all(a["position"][0] in (-10.0, 10.0) for a in actions), actions


@pytest.mark.parametrize("way_out", ["shutdown", "SIGINT", "SIGTERM"])
def test_every_way_out_of_active_ends_with_the_safe_action(
    tiny_run: Path, probe: Probe, way_out: str
) -> None:
    probe.ask("subscribe", id="act", topic="/robot/effort", type=JOINT_STATE, keep_all=True)
    with command("agent", "run", str(tiny_run), *ARGS, ready="Ctrl-C stops it") as agent:
        activate_and_act(probe, agent)
        if way_out == "shutdown":  # from active; once finalized the process ends by itself
            assert probe.ask("lifecycle_change", node=NODE, transition="shutdown_active") == {"success": True}
            agent.process.wait(timeout=60)
        else:
            agent.stop(getattr(signal, way_out), timeout_s=60)
        assert agent.process.returncode == 0, agent.output
        actions = probe.ask("wait_count", id="act", count=4)
        assert isinstance(actions, list), agent.output
        assert [a["position"] for a in actions][3:] == [[0.0]], actions  # the safe action, last
        assert "safe action [0.0] sent" in " ".join(agent.output.split()), agent.output
        assert "Traceback" not in agent.output, agent.output


def test_lifecycle_services_answer_while_configure_loads_the_policy(tiny_run: Path, probe: Probe) -> None:
    """configure imports stable-baselines3 and loads the policy (seconds); get_state answers
    meanwhile (``configuring``), before configure's own answer."""
    with command("agent", "run", str(tiny_run), *ARGS, ready="Ctrl-C stops it") as agent:
        assert probe.ask("lifecycle_clients", node=NODE)
        assert probe.ask("lifecycle_change_async", node=NODE, transition="configure")
        # a get_state may overtake the configure request on a busy machine (still unconfigured):
        # ask until the transition has begun; a node whose services wait for configure says inactive
        state = probe.wait(
            lambda: (s := probe.ask("lifecycle_get", node=NODE))["label"] != "unconfigured" and s,
            timeout_s=120.0,
            what="configure under way",
        )
        done = probe.ask("lifecycle_wait", node=NODE, timeout=120)
        assert done["success"], agent.output
        assert state["t"] < done["t"] and state["label"] == "configuring", (state, done)
        assert probe.ask("lifecycle_get", node=NODE)["label"] == "inactive"
