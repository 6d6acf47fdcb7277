"""The ROS 2 view of an FMU node (a real subprocess), checked by a peer written from the rmw_zenoh
design document alone: plain zenoh-python, literal key expressions, struct and rosbags."""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.env import RemoteFmuEnv
from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, node_process, wait_for

pytestmark = pytest.mark.integration
JAZZY = get_typestore(Stores.ROS2_JAZZY)
JOINT_STATE = "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"  # noqa: E501
TRIGGER = (
    "std_srvs::srv::dds_::Trigger_/RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
)
CLOCK = (
    "rosgraph_msgs::msg::dds_::Clock_/RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564"
)
FLOAT64 = (
    "std_msgs::msg::dds_::Float64_/RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a"
)
CARTPOLE = example_experiment("cartpole_balance")


def collect(session: Any, key: str) -> tuple[list[tuple[Any, bytes]], Any]:
    received: list[tuple[Any, bytes]] = []
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        with lock:
            received.append(
                (sample.payload.to_bytes(), sample.attachment.to_bytes() if sample.attachment else b"")
            )

    return received, session.declare_subscriber(key, on_sample)


def test_outputs_as_joint_states_stamped_with_simulation_time(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "sim", loopback, "--ros", "--ros-domain", "7"):
        session = loopback.session
        received, sub = collect(session, f"7/sim/outputs/{JOINT_STATE}")
        tokens = wait_for(
            lambda: {
                str(r.ok.key_expr)
                for r in session.liveliness().get("@ros2_lv/7/**", timeout=2.0)
                if r.ok and "/NN/" in str(r.ok.key_expr)
            }
        )
        assert any(token.endswith("/NN/%/%/sim") for token in tokens)  # node /sim, root namespace and enclave
        # No pause for the subscription: the env's info query and reset reach the node after the
        # subscriber's declaration (one link from this session through the router, in order), and
        # the node publishes the joint states from the session that answers them.
        env = RemoteFmuEnv(CARTPOLE, "sim", session=session, prefix=loopback.prefix)
        try:
            _, info = env.reset(seed=0)
            sent = [info["outputs"]]
            for _ in range(5):
                _, _, _, _, info = env.step(1)
                sent.append(info["outputs"])
            wait_for(lambda: len(received) >= 6)  # step 0 (at reset) and five steps
        finally:
            env.close()
            sub.undeclare()
        messages = [
            JAZZY.deserialize_cdr(payload, "sensor_msgs/msg/JointState") for payload, _ in received[-6:]
        ]
        for k, message in enumerate(messages):
            assert list(message.name) == ["x", "x_dot", "theta", "theta_dot"]
            np.testing.assert_array_equal(message.position, sent[k])
            assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == round(k * 0.02 * 1e9)
        sequence = [struct.unpack_from("<q", attachment)[0] for _, attachment in received[-6:]]
        assert sequence == list(range(sequence[0], sequence[0] + 6))
        assert all(len(a) == 33 and a[16] == 16 for _, a in received)


def test_reset_service_and_actions_in_real_time(loopback: Loopback) -> None:
    with node_process(
        CARTPOLE, "rt", loopback, "--ros", "--mode", "realtime", "--rate", "4", "--ros-backend", "zenoh"
    ):
        session = loopback.session
        outputs, sub = collect(session, f"0/rt/outputs/{JOINT_STATE}")
        clock, clock_sub = collect(session, f"0/clock/{CLOCK}")
        try:
            wait_for(lambda: len(outputs) > 20 and len(clock) > 20)
            action_key = f"0/rt/actions/{JOINT_STATE}"
            header = JAZZY.types["std_msgs/msg/Header"](
                stamp=JAZZY.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
            )
            push = JAZZY.types["sensor_msgs/msg/JointState"](
                header=header,
                name=["force"],
                position=np.array([10.0]),
                velocity=np.array([], dtype=float),
                effort=np.array([], dtype=float),
            )
            gid = bytes(range(16))
            for seq in range(3):
                session.put(
                    action_key,
                    bytes(JAZZY.serialize_cdr(push, "sensor_msgs/msg/JointState")),
                    attachment=struct.pack("<qqB16s", seq, time.time_ns(), 16, gid),
                )

            def x_dot() -> float:
                return float(JAZZY.deserialize_cdr(outputs[-1][0], "sensor_msgs/msg/JointState").position[1])

            assert wait_for(lambda: x_dot() > 1.0, 10.0)  # the held +10 N push accelerates the cart
            request = bytes.fromhex("0001000000")  # std_srvs/srv/Trigger request: CDR header + one pad byte
            replies = list(
                session.get(
                    f"0/rt/reset/{TRIGGER}",
                    payload=request,
                    timeout=30.0,
                    attachment=struct.pack("<qqB16s", 1, time.time_ns(), 16, gid),
                )
            )
            payload = bytes(replies[0].ok.payload.to_bytes())
            # std_srvs/srv/Trigger response in CDR: header, bool success, pad to 4, string message
            assert payload[:4] == b"\x00\x01\x00\x00"
            success = payload[4] == 1
            (length,) = struct.unpack_from("<I", payload, 8)
            message = payload[12 : 12 + length - 1].decode()
            assert success and "reset to t0" in message
            stamp = clock[-1][0]
            assert len(stamp) == 12 and stamp[:4] == b"\x00\x01\x00\x00"
        finally:
            sub.undeclare()
            clock_sub.undeclare()


def test_per_variable_float64_topics(loopback: Loopback, tmp_path: Any) -> None:
    experiment = tmp_path / "cartpole.yaml"
    experiment.write_text(CARTPOLE.read_text() + "\nros: {per_variable: true, namespace: /lab}\n")
    with node_process(experiment, "cp", loopback, "--ros"):
        session = loopback.session
        theta, sub = collect(session, f"0/lab/cp/out/theta/{FLOAT64}")
        env = RemoteFmuEnv(experiment, "cp", session=session, prefix=loopback.prefix)
        try:
            env.reset(seed=0)
            _, _, _, _, info = env.step(0)
            wait_for(lambda: len(theta) >= 2)  # step 0 (published at reset) and step 1
            value = JAZZY.deserialize_cdr(theta[-1][0], "std_msgs/msg/Float64").data
            assert value == info["outputs"][2]
        finally:
            env.close()
            sub.undeclare()


def test_rclpy_backend_without_ros_says_how_to_install_it(loopback: Loopback) -> None:
    """Where rclpy is missing, ``--ros-backend rclpy`` is a one-paragraph error with the install line."""
    import importlib.util
    import subprocess
    import sys

    if importlib.util.find_spec("rclpy") is not None:
        pytest.skip("rclpy is installed here: tests/ros runs the rclpy backend itself")
    cmd = [sys.executable, "-m", "bridge.cli", "node", str(CARTPOLE), "--name", "r", "--connect"]
    cmd += [loopback.endpoint, "--prefix", loopback.prefix, "--ros-backend", "rclpy"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert "rclpy is needed for the rclpy backend" in result.stderr
    assert "pip install 'fmu-bridge[ros]'" in " ".join(result.stderr.split())
