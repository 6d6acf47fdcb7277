"""FMU parameters as ROS parameters on the zenoh backend, called as ``ros2 param`` calls them (the
node's ``rcl_interfaces`` parameter services) by zenoh-ros2-sdk (PyPI): an independent implementation of
rmw_zenoh's wire that takes the services' types and type hashes from the installed ``.srv`` files.
The same rules as on the rclpy backend (``test_fmu_parameters.py``): the declared range, a refusal
inside an episode with its reason, a set between episodes applied at the next ``~/reset``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback
from tests.ros.conftest import command
from tests.ros.test_zenoh_sdk_view import sdk_installed  # noqa: F401  # a fixture: skip or fail without it

DCMOTOR = example_experiment("dcmotor_tracking")  # R and J randomised: a reset may set them
PEER = Path(__file__).parent / "zenoh_sdk_params.py"


class SdkPeer:
    """``zenoh_sdk_params.py`` as a process: ``ask(op, **fields)`` returns its answer."""

    def __init__(self, port: str, domain: int, node: str, env: dict[str, str]) -> None:
        self.process = subprocess.Popen(
            [sys.executable, str(PEER), port, str(domain), node],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env,
        )  # fmt: skip
        assert self._line(120.0) == {"ready": True}

    def _line(self, timeout_s: float) -> Any:
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(self.process.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        reader.start()
        reader.join(timeout_s)
        if not result or not result[0]:
            pytest.fail(f"the zenoh-ros2-sdk peer did not answer within {timeout_s} s")
        return json.loads(result[0])

    def ask(self, op: str, **fields: Any) -> Any:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps({"op": op, **fields}) + "\n")
        self.process.stdin.flush()
        answer = self._line(300.0)
        if "error" in answer:
            pytest.fail(f"sdk peer {op}: {answer['error']}")
        return answer["ok"]

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(timeout=10)
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()


@pytest.fixture
def zenoh_node(loopback: Loopback, ros_domain: int, tmp_path: Path) -> Iterator[tuple[SdkPeer, Any]]:
    args = [
        "node", str(DCMOTOR), "--name", "plant", "--connect", loopback.endpoint, "--prefix", loopback.prefix,
        "--ros-backend", "zenoh", "--ros-domain", str(ros_domain),
    ]  # fmt: skip
    env = {
        **os.environ,
        "ZENOH_CONFIG_OVERRIDE": 'listen/endpoints=["tcp/127.0.0.1:0"]',  # loopback only
        "ZENOH_ROS2_SDK_CACHE": str(tmp_path / "sdk-cache"),
        "GIT_ALLOW_PROTOCOL": "file",  # offline: a clone of a message repository would fail
    }
    with command(*args) as node:
        peer = SdkPeer(loopback.endpoint.rsplit(":", 1)[1], ros_domain, "plant", env)
        try:
            yield peer, node
        finally:
            peer.close()


def test_ros2_param_on_the_zenoh_backend_sets_fmu_parameters_between_episodes(
    zenoh_node: tuple[SdkPeer, Any],
) -> None:
    peer, node = zenoh_node
    assert {"J", "R"} <= set(peer.ask("list"))
    described = peer.ask("describe", name="R")
    assert described["type"] == 3 and described["ranges"][0][0] == 0.0, described  # a double, R >= 0
    assert "next ~/reset" in described["description"]
    assert peer.ask("get", name="R") == {"type": 3, "double": 1.0}  # the FMU's start value
    assert peer.ask("types", names=["R", "no_such"]) == [3, 0]  # an undeclared one: not set
    below = peer.ask("set", name="R", value=-1.0)
    assert not below["successful"] and "outside its declared range [0," in below["reason"], below
    integer = peer.ask("set", name="R", value=4)  # `ros2 param set /plant R 4` sends an integer
    assert not integer["successful"] and "is a double, got a integer" in integer["reason"], integer
    assert peer.ask("reset")["success"]
    nominal = peer.ask("episode", volts=12.0, n=300)  # a whole episode (3 s at 10 ms): it has ended
    assert len(nominal) == 300
    assert peer.ask("set", name="R", value=4.0) == {"successful": True, "reason": ""}, node.output
    assert peer.ask("get", name="R") == {"type": 3, "double": 4.0}
    assert peer.ask("reset")["success"]
    resistive = peer.ask("episode", volts=12.0, n=5)  # applied at this reset; the episode goes on
    refused = peer.ask("set", name="R", value=1.0)
    assert not refused["successful"] and "inside episode 2 (step 5)" in refused["reason"], refused
    atomically = peer.ask(
        "set_atomically", parameters=[{"name": "J", "value": 0.02}, {"name": "R", "value": 1.0}]
    )
    assert not atomically["successful"] and "inside episode 2" in atomically["reason"], atomically
    assert peer.ask("get", name="R") == {"type": 3, "double": 4.0}
    # 12 V into the armature: the current rises towards V/R, so four times R gives a smaller one
    assert all(r < n for r, n in zip(resistive, nominal[:5])), (resistive, nominal[:5])
    assert resistive[-1] < 0.5 * nominal[4], (resistive, nominal[:5])


@pytest.mark.parametrize(
    "srv",
    [
        "ListParameters", "GetParameters", "GetParameterTypes", "DescribeParameters", "SetParameters",
        "SetParametersAtomically",
    ],
)  # fmt: skip
def test_parameter_service_type_hashes_are_the_ones_rosidl_wrote_into_rcl_interfaces(srv: str) -> None:
    """The keys and tokens of our parameter services carry rosidl's hash, read back from the
    installed package's type description (``share/rcl_interfaces/srv/<Srv>.json``)."""
    from bridge.net.ros2.typehash import type_hash

    described = json.loads(
        (Path(sys.prefix) / "share" / "rcl_interfaces" / "srv" / f"{srv}.json").read_text()
    )
    expected = {h["type_name"]: h["hash_string"] for h in described["type_hashes"]}
    assert type_hash(f"rcl_interfaces/srv/{srv}") == expected[f"rcl_interfaces/srv/{srv}"]
