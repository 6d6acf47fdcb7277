"""``fmu-bridge node --managed``: the FMU node as a lifecycle node, driven from a separate plain-rclpy
process as ``ros2 lifecycle set`` drives it: configure loads the FMU (topics appear, nothing steps),
activate steps it, deactivate stops it, cleanup closes it, shutdown ends the process."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from bridge.errors import TransportError
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.discovery import query_info
from bridge.net.remote import RemotePlant
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
CARTPOLE = example_experiment("cartpole_balance")
JOINT_STATE = "sensor_msgs/msg/JointState"
NODE = "/plant"


def settle(probe: Probe, quiet_s: float = 1.0, within_s: float = 30.0) -> None:
    """Take what arrives until nothing has come for ``quiet_s`` (samples already on the way when
    the node stopped reach a busy reader late); fails if the outputs never stop for that long."""
    end = time.monotonic() + within_s
    while time.monotonic() < end:
        if quiet_for(probe, quiet_s) == []:
            return
    raise AssertionError(f"the outputs did not stop for {quiet_s} s within {within_s} s")


def quiet_for(probe: Probe, seconds: float) -> list[object]:
    """What arrives on the outputs in the next ``seconds`` (a check that nothing steps)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.1)
    return list(probe.ask("take", id="out"))


def node_counters(loopback: Loopback) -> dict[str, Any]:
    """The node's counters from its native ``info`` reply."""
    counters: dict[str, Any] = query_info(loopback.session, proto.Keys(loopback.prefix, "plant"), 60.0)[
        "counters"
    ]
    return counters


def test_the_fmu_node_as_a_lifecycle_node(loopback: Loopback, probe: Probe) -> None:
    args = [
        "node", str(CARTPOLE), "--name", "plant", "--connect", loopback.endpoint, "--prefix",
        loopback.prefix, "--mode", "realtime", "--ros-backend", "rclpy", "--managed",
    ]  # fmt: skip
    probe.ask("subscribe", id="out", topic="/plant/outputs", type=JOINT_STATE, keep_all=True)
    with command(*args, ready="Ctrl-C stops it") as node:
        assert probe.ask("lifecycle_get", node=NODE)["label"] == "unconfigured"
        assert probe.ask("topic_info", topic="/plant/outputs") == []  # no FMU loaded yet
        for round_ in range(2):  # configured, active, inactive, cleaned up; then once more
            assert probe.ask("lifecycle_change", node=NODE, transition="configure") == {"success": True}
            assert probe.ask("lifecycle_get", node=NODE)["label"] == "inactive"
            probe.wait(lambda: probe.ask("topic_info", topic="/plant/outputs"), what="the outputs publisher")
            probe.ask("publish", topic="/plant/actions", type=JOINT_STATE,
                      messages=[{"stamp_ns": 0, "name": ["force"], "position": [1.0]}])  # fmt: skip
            assert quiet_for(probe, 1.0) == []  # loaded, not stepping; the action was refused
            assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
            outputs = probe.ask("wait_count", id="out", count=10, timeout=30)
            assert isinstance(outputs, list), node.output
            assert outputs[0]["stamp_ns"] == 0  # the episode starts at activation
            assert probe.ask("lifecycle_change", node=NODE, transition="deactivate") == {"success": True}
            settle(probe)
            assert quiet_for(probe, 1.0) == []  # its clock stopped (a running one: 50 samples/s)
            if round_ == 0:
                assert probe.ask("lifecycle_change", node=NODE, transition="cleanup") == {"success": True}
                probe.wait(
                    lambda: probe.ask("topic_info", topic="/plant/outputs") == [],
                    what="the outputs publisher gone after cleanup",
                )
        assert "ROS action rejected (the managed node is not active" in " ".join(node.output.split())
        assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
        assert isinstance(probe.ask("wait_count", id="out", count=5, timeout=30), list)
        # shutdown from active: finalized, and the process ends by itself
        assert probe.ask("lifecycle_change", node=NODE, transition="shutdown_active") == {"success": True}
        node.process.wait(timeout=30)
        assert node.process.returncode == 0 and "Traceback" not in node.output, node.output


def test_a_managed_node_that_is_not_active_refuses_native_clients_too(
    loopback: Loopback, probe: Probe
) -> None:
    """The native Zenoh path (a RemotePlant, as a trainer's remote env drives it) follows the same
    rule as ROS actions: no node before configure, and no reset or step while inactive, each
    refused with the reason; activated, the same client resets and steps, and a deactivated
    node's episode resumes at the step it stopped at once activated again."""
    args = [
        "node", str(CARTPOLE), "--name", "plant", "--connect", loopback.endpoint, "--prefix",
        loopback.prefix, "--ros-backend", "rclpy", "--managed",
    ]  # fmt: skip
    where = {"session": loopback.session, "prefix": loopback.prefix}
    with command(*args, ready="Ctrl-C stops it") as node:
        with pytest.raises(TransportError, match="plant"):  # unconfigured: no FMU, no native keys
            RemotePlant("plant", timeout_s=1.0, **where)
        assert probe.ask("lifecycle_change", node=NODE, transition="configure") == {"success": True}
        plant = RemotePlant("plant", timeout_s=60.0, **where)
        try:
            plant.bind(["force"], ["x", "x_dot", "theta", "theta_dot"])
            with pytest.raises(
                TransportError, match=r"reset was refused \(inactive\): the managed node is not active"
            ):
                plant.reset({}, None)
            assert plant.client.description["active"] is False  # and its info says so
            assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
            start = plant.reset({}, None)
            pushed = [plant.step(np.array([10.0])) for _ in range(3)]
            assert pushed[-1][1] > 0.0 and start[1] == 0.0  # x_dot: the cart moves under +10 N
            assert probe.ask("lifecycle_change", node=NODE, transition="deactivate") == {"success": True}
            with pytest.raises(
                TransportError, match=r"rejected step 4 of episode \d+: inactive: the managed node"
            ):
                plant.step(np.array([10.0]))
            assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
            resumed = plant.step(np.array([10.0]))  # step 4 of the same episode: the state was kept
            assert plant.sample == 4 and resumed[1] > pushed[-1][1], (resumed, pushed[-1])
            assert probe.ask("lifecycle_change", node=NODE, transition="deactivate") == {"success": True}
            with pytest.raises(TransportError, match=r"refused \(inactive\)"):
                plant.reset({}, None)
            assert probe.ask("lifecycle_change", node=NODE, transition="activate") == {"success": True}
            assert plant.reset({}, None)[1] == 0.0 and plant.step(np.array([-10.0]))[1] < 0.0
        finally:
            plant.close()
        counters = node_counters(loopback)
        assert counters["rejected_inactive"] == 1 and counters["reset_inactive"] == 2, node.output
