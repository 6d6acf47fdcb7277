"""The rmw_zenoh view of an FMU node checked by zenoh-ros2-sdk (PyPI): an independent implementation of
rmw_zenoh's wire, run offline with the message definitions of the installed ROS packages. It finds the
node's topics with their types, subscribes to its outputs (its own type hash must match ours, or no
sample arrives) and pushes the cart with actions it publishes."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import command

CARTPOLE = example_experiment("cartpole_balance")
PEER = Path(__file__).parent / "zenoh_sdk_peer.py"
INSTALL = "pip install zenoh-ros2-sdk==0.1.8"
NAMES = ["x", "x_dot", "theta", "theta_dot"]


@pytest.fixture(autouse=True)
def sdk_installed() -> None:
    if importlib.util.find_spec("zenoh_ros2_sdk") is None:
        message = f"zenoh-ros2-sdk is not installed; install it with: {INSTALL}"
        if os.environ.get("FMU_BRIDGE_REQUIRE_ROS") == "1":
            pytest.fail(message)
        pytest.skip(message)


def test_zenoh_ros2_sdk_sees_the_outputs_and_pushes_the_cart(
    loopback: Loopback, ros_domain: int, tmp_path: Path
) -> None:
    args = [
        "node", str(CARTPOLE), "--name", "sim", "--connect", loopback.endpoint, "--prefix", loopback.prefix,
        "--mode", "realtime", "--ros-backend", "zenoh", "--ros-domain", str(ros_domain),
    ]  # fmt: skip
    env = {
        **os.environ,
        "ZENOH_CONFIG_OVERRIDE": 'listen/endpoints=["tcp/127.0.0.1:0"]',  # loopback only
        "ZENOH_ROS2_SDK_CACHE": str(tmp_path / "sdk-cache"),  # empty: nothing cached before
        "GIT_ALLOW_PROTOCOL": "file",  # offline: a clone of a message repository would fail
    }
    port = loopback.endpoint.rsplit(":", 1)[1]
    with command(*args):
        peer = [sys.executable, str(PEER), port, str(ros_domain), "sim", "20", "10"]
        done = subprocess.run(peer, capture_output=True, text=True, timeout=300, env=env, check=False)
    assert done.returncode == 0 and done.stdout.strip(), done.stderr[-3000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    topics = {name: types for name, types in seen["topics"]}
    assert topics["/sim/outputs"] == ["sensor_msgs/msg/JointState"]
    assert topics["/sim/actions"] == ["sensor_msgs/msg/JointState"]
    assert topics["/clock"] == ["rosgraph_msgs/msg/Clock"]
    before, after = seen["before"], seen["after"]
    assert len(before) >= 20 and len(after) >= 20
    assert all(m["name"] == NAMES for m in before + after)
    stamps = np.array([m["stamp_ns"] for m in before + after])
    assert np.all(stamps % 20_000_000 == 0) and np.all(np.diff(stamps) > 0)  # simulation time, 20 ms grid
    assert all(m["position"][1] == 0.0 for m in before)  # at rest before any action
    assert after[-1]["position"][1] > 1.0  # the held +10 N push accelerates the cart
