"""``fmu-bridge node --ros-backend rclpy`` against real rclpy, seen from a plain-rclpy process."""

from __future__ import annotations

import itertools
import os
import signal
from pathlib import Path

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import Probe, command

pytestmark = [pytest.mark.ros, pytest.mark.integration]
CARTPOLE = example_experiment("cartpole_balance")
OUTPUTS = ["x", "x_dot", "theta", "theta_dot"]
HASHES = {  # REP-2011 type hashes of Jazzy's interfaces
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "std_msgs/msg/Float64": "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
}
JOINT_STATE = "sensor_msgs/msg/JointState"
DT_NS = 20_000_000  # the experiment's sampling time


def node_args(experiment: Path, name: str, net: Loopback, *extra: str) -> list[str]:
    return [
        "node", str(experiment), "--name", name, "--connect", net.endpoint, "--prefix", net.prefix,
        "--ros-backend", "rclpy", *extra,
    ]  # fmt: skip


RCL_STANDARD = {"/rosout", "/parameter_events"}  # every rclpy node has them


def own(topics: dict[str, list[str]]) -> dict[str, list[str]]:
    return {k: v for k, v in topics.items() if k not in RCL_STANDARD}


def wait_node(probe: Probe, fqn: str) -> None:
    probe.wait(lambda: fqn in probe.ask("nodes"), what=f"node {fqn} in the ROS graph")


def test_graph_types_qos_and_type_hashes(loopback: Loopback, probe: Probe, ros_domain: int) -> None:
    with command(*node_args(CARTPOLE, "sim", loopback, "--mode", "realtime")):
        wait_node(probe, "/sim")
        info = probe.wait(
            lambda: (i := probe.ask("node_info", name="sim"))["services"].get("/sim/reset") and i,
            what="the reset service",
        )
        assert info["publishers"]["/sim/outputs"] == ["sensor_msgs/msg/JointState"]
        assert info["publishers"]["/clock"] == ["rosgraph_msgs/msg/Clock"]
        assert info["subscriptions"]["/sim/actions"] == ["sensor_msgs/msg/JointState"]
        assert info["services"]["/sim/reset"] == ["std_srvs/srv/Trigger"]
        for topic, type_name in (
            ("/sim/outputs", "sensor_msgs/msg/JointState"),
            ("/clock", "rosgraph_msgs/msg/Clock"),
        ):
            (publisher,) = probe.ask("topic_info", topic=topic)
            assert publisher["node"] == "/sim" and publisher["type"] == type_name
            assert publisher["type_hash"] == HASHES[type_name]
            assert (publisher["reliability"], publisher["durability"]) == ("reliable", "volatile")


def test_rate_and_clock_follow_simulation_time(loopback: Loopback, probe: Probe) -> None:
    probe.ask("subscribe", id="out", topic="/sim/outputs", type=JOINT_STATE, keep_all=True)
    probe.ask("subscribe", id="clock", topic="/clock", type="rosgraph_msgs/msg/Clock", keep_all=True)
    with command(*node_args(CARTPOLE, "sim", loopback, "--mode", "realtime")) as node:
        outputs = probe.ask("wait_count", id="out", count=101)
        clock = probe.ask("take", id="clock")
        said = " ".join(node.output.split())
    assert isinstance(outputs, list), outputs
    stamps = [m["stamp_ns"] for m in outputs]
    assert all(m["name"] == OUTPUTS for m in outputs)
    # one sample per sampling time (50 Hz in simulation time), in order, none repeated; the node's
    # KEEP_LAST 10 publisher may drop samples a starved reader has not taken yet: most arrive
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert all(g > 0 and g % DT_NS == 0 for g in gaps), stamps[:20]
    assert gaps.count(DT_NS) >= 0.9 * len(gaps), gaps
    # the clock carries the same simulation time as the outputs' stamps
    assert set(stamps[1:-1]) <= {m["stamp_ns"] for m in clock}
    # paced by simulation time at --rate 1, never faster than real time (how close it keeps to
    # real time is a figure of benchmarks/bench_realtime.py, not of a test on a shared machine)
    rtf = (stamps[-1] - stamps[0]) / 1e9 / (outputs[-1]["t"] - outputs[0]["t"])
    assert rtf < 1.5, (rtf, said)


def test_lockstep_actions_reset_and_no_lost_steps(loopback: Loopback, probe: Probe) -> None:
    """50 actions back to back: 50 steps, none lost. The node keeps every action it has received
    (KEEP_ALL in lockstep); the publisher keeps all 50 too (depth 64): a depth-10 writer may itself
    overwrite samples its reader has not acknowledged yet, which DDS allows under load."""
    probe.ask("subscribe", id="out", topic="/sim/outputs", type="sensor_msgs/msg/JointState", keep_all=True)
    with command(*node_args(CARTPOLE, "sim", loopback, "--mode", "lockstep")):
        answer = probe.ask("trigger", service="/sim/reset")
        assert answer["success"], answer
        first = probe.ask("wait_count", id="out", count=1)
        assert first[0]["stamp_ns"] == 0
        probe.ask("take", id="out")
        pushes = [{"name": ["force"], "position": [10.0 if i % 2 else -10.0]} for i in range(50)]
        sent = probe.ask("publish", topic="/sim/actions", type=JOINT_STATE, messages=pushes, depth=64)
        assert sent == 50
        outputs = probe.ask("wait_count", id="out", count=50, timeout=60)
        assert isinstance(outputs, list), f"only {len(outputs['messages'])} of 50 steps"
        assert [m["stamp_ns"] for m in outputs] == [DT_NS * (i + 1) for i in range(50)]
        # a reset answers and starts again at t0
        answer = probe.ask("trigger", service="/sim/reset")
        assert answer["success"] and "episode" in answer["message"], answer
        again = probe.ask("wait_count", id="out", count=51)
        assert again[-1]["stamp_ns"] == 0


def test_per_variable_topics(loopback: Loopback, probe: Probe, tmp_path: Path) -> None:
    experiment = tmp_path / "cartpole.yaml"
    experiment.write_text(CARTPOLE.read_text() + "\nros: {per_variable: true, namespace: /lab}\n")
    probe.ask("subscribe", id="out", topic="/lab/cp/outputs", type=JOINT_STATE, keep_all=True)
    probe.ask("subscribe", id="theta", topic="/lab/cp/out/theta", type="std_msgs/msg/Float64", keep_all=True)
    with command(*node_args(experiment, "cp", loopback, "--mode", "lockstep")):
        wait_node(probe, "/lab/cp")
        assert probe.ask("trigger", service="/lab/cp/reset")["success"]
        pushes = [{"data": 10.0}] * 3
        probe.ask("publish", topic="/lab/cp/in/force", type="std_msgs/msg/Float64", messages=pushes)
        outputs = probe.ask("wait_count", id="out", count=4)
        theta = probe.ask("wait_count", id="theta", count=4)
    assert [m["stamp_ns"] for m in outputs] == [0, DT_NS, 2 * DT_NS, 3 * DT_NS]  # one step per value
    assert [t["data"] for t in theta] == [m["position"][2] for m in outputs]


def test_ros_args_remap_namespace_node_name_and_parameters(loopback: Loopback, probe: Probe) -> None:
    extra = [
        "--mode", "realtime", "--ros-args", "-r", "__ns:=/robot", "-r", "__node:=plant",
        "-r", "outputs:=joint_states", "-p", "clock:=false", "--",
    ]  # fmt: skip
    with command(*node_args(CARTPOLE, "sim", loopback, *extra)):
        wait_node(probe, "/robot/plant")
        info = probe.wait(
            lambda: (i := probe.ask("node_info", name="plant", namespace="/robot"))["publishers"] and i,
            what="publishers of /robot/plant",
        )
        assert own(info["publishers"]) == {"/robot/joint_states": ["sensor_msgs/msg/JointState"]}  # no /clock
        assert "/robot/plant/reset" in info["services"]
        assert own(info["subscriptions"]) == {"/robot/plant/actions": ["sensor_msgs/msg/JointState"]}


def test_domain_isolation(loopback: Loopback, probe: Probe, ros_domain: int) -> None:
    """``--ros-domain`` is honoured: the node lives in its domain, not in the environment's."""
    other = ros_domain % 100 + 101  # 101..200: never the probe's
    with command(*node_args(CARTPOLE, "iso", loopback, "--mode", "realtime", "--ros-domain", str(other))):
        there = Probe({**os.environ, "ROS_DOMAIN_ID": str(other)})
        try:
            wait_node(there, "/iso")
            there.ask("subscribe", id="out", topic="/iso/outputs", type="sensor_msgs/msg/JointState")
            assert isinstance(there.ask("wait_count", id="out", count=5), list)
        finally:
            there.close()
        probe.ask("subscribe", id="out", topic="/iso/outputs", type="sensor_msgs/msg/JointState")
        late = probe.ask("wait_count", id="out", count=1, timeout=3.0)  # the node publishes 50/s
        assert late == {"timeout": True, "messages": []}
        assert "/iso" not in probe.ask("nodes")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_node_exits_cleanly_and_promptly(loopback: Loopback, probe: Probe, sig: int) -> None:
    with command(*node_args(CARTPOLE, "sim", loopback, "--mode", "realtime")) as node:
        wait_node(probe, "/sim")
        elapsed = node.stop(sig)
        assert node.process.returncode == 0, node.output
    # a clean exit takes a few tenths of a second; 3 s leaves room for a loaded machine, while a
    # hang (killed after 10 s) or a wait on a timeout of its own still fails
    assert elapsed < 3.0, f"{elapsed:.2f} s"
    for noise in ("Traceback", "Exception", "Error"):
        assert noise not in node.output, node.output
    probe.wait(lambda: "/sim" not in probe.ask("nodes"), what="the node gone from the graph")
