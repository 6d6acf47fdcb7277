"""``ros2 param`` against a node on the zenoh backend, over rmw_zenoh's wire through zenoh-ros2-sdk (PyPI),
not fmu-bridge: its service clients take their types and type hashes from the installed
``rcl_interfaces`` ``.srv`` files. Reads JSON commands from stdin, one a line, and answers each with
one JSON line, as ``probe.py`` does for rclpy.

    python zenoh_sdk_params.py PORT DOMAIN NODE

Commands: ``{"op": "list"}``, ``{"op": "describe", "name": N}``, ``{"op": "get", "name": N}``,
``{"op": "types", "name": N}``, ``{"op": "set", "name": N, "value": V}`` (V a float or an int: sent as
that ROS type), ``{"op": "set_atomically", ...}``, ``{"op": "reset"}`` (``~/reset``), ``{"op":
"episode", "volts": V, "n": N}`` (N lockstep actions on ``~/actions``; the ``current`` output of each
sample after step 0), ``{"op": "quit"}``.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

NESTED = (
    "ParameterValue", "Parameter", "FloatingPointRange", "IntegerRange", "ParameterDescriptor",
    "SetParametersResult", "ListParametersResult",
)  # fmt: skip


class Peer:
    def __init__(self, port: int, domain: int, node: str) -> None:
        from zenoh_ros2_sdk.message_registry import get_registry

        get_registry(str(Path(sys.prefix) / "share"))  # the installed ROS packages' definitions
        self.where = {"domain_id": domain, "router_ip": "127.0.0.1", "router_port": port}
        from zenoh_ros2_sdk.session import ZenohSession

        session = ZenohSession.get_instance("127.0.0.1", port)
        for nested in NESTED:  # from the installed .msg files, into the store its clients decode with
            session.register_message_type(None, f"rcl_interfaces/msg/{nested}")
        self.node = node
        self.clients: dict[str, Any] = {}
        self.outputs: list[Any] = []
        self.lock = threading.Lock()
        self.sub: Any = None
        self.pub: Any = None

    def call(self, service: str, srv: str, **fields: Any) -> Any:
        from zenoh_ros2_sdk import ROS2ServiceClient

        if service not in self.clients:
            self.clients[service] = ROS2ServiceClient(
                f"/{self.node}/{service}", srv, *definitions(srv), timeout=5.0,
                type_hash=installed_hash(srv), **self.where,
            )  # fmt: skip
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # no route yet on a just-opened session: ask again
            answer = self.clients[service].call(**fields)
            if answer is not None:
                return answer
            time.sleep(0.2)
        raise RuntimeError(f"/{self.node}/{service} did not answer in 60 s")

    def value(self, number: float | int) -> Any:
        import numpy as np
        from zenoh_ros2_sdk import get_message_class

        kind = 2 if isinstance(number, int) else 3  # PARAMETER_INTEGER, PARAMETER_DOUBLE
        cls = get_message_class("rcl_interfaces/msg/ParameterValue")
        arrays = {f"{k}_array_value": np.array([], dtype=t) for k, t in (("byte", np.uint8), ("bool", bool))}
        arrays |= {"integer_array_value": np.array([], dtype=np.int64)}
        arrays |= {"double_array_value": np.array([], dtype=np.float64)}
        return cls(
            type=kind, bool_value=False, integer_value=int(number), double_value=float(number),
            string_value="", string_array_value=[], **arrays,
        )  # fmt: skip

    def op_list(self, _: dict[str, Any]) -> Any:
        answer = self.call("list_parameters", "rcl_interfaces/srv/ListParameters", prefixes=[], depth=0)
        return list(answer.result.names)

    def op_describe(self, c: dict[str, Any]) -> Any:
        answer = self.call("describe_parameters", "rcl_interfaces/srv/DescribeParameters", names=[c["name"]])
        d = answer.descriptors[0]
        ranges = [[r.from_value, r.to_value] for r in d.floating_point_range]
        return {"name": d.name, "type": int(d.type), "description": d.description, "ranges": ranges}

    def op_get(self, c: dict[str, Any]) -> Any:
        answer = self.call("get_parameters", "rcl_interfaces/srv/GetParameters", names=[c["name"]])
        v = answer.values[0]
        return {"type": int(v.type), "double": float(v.double_value)}

    def op_types(self, c: dict[str, Any]) -> Any:
        answer = self.call("get_parameter_types", "rcl_interfaces/srv/GetParameterTypes", names=c["names"])
        return [int(t) for t in answer.types]

    def _parameter(self, c: dict[str, Any]) -> Any:
        from zenoh_ros2_sdk import get_message_class

        return get_message_class("rcl_interfaces/msg/Parameter")(name=c["name"], value=self.value(c["value"]))

    def op_set(self, c: dict[str, Any]) -> Any:
        answer = self.call(
            "set_parameters", "rcl_interfaces/srv/SetParameters", parameters=[self._parameter(c)]
        )
        return {"successful": bool(answer.results[0].successful), "reason": answer.results[0].reason}

    def op_set_atomically(self, c: dict[str, Any]) -> Any:
        answer = self.call(
            "set_parameters_atomically",
            "rcl_interfaces/srv/SetParametersAtomically",
            parameters=[self._parameter(p) for p in c["parameters"]],
        )
        return {"successful": bool(answer.result.successful), "reason": answer.result.reason}

    def op_reset(self, _: dict[str, Any]) -> Any:
        answer = self.call("reset", "std_srvs/srv/Trigger")
        return {"success": bool(answer.success), "message": answer.message}

    def op_episode(self, c: dict[str, Any]) -> Any:
        import numpy as np
        from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_message_class

        def on_message(msg: Any) -> None:
            with self.lock:
                stamp = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
                if stamp > 0:  # step 0 (the reset's sample) is not an answer to an action
                    self.outputs.append((list(msg.name), msg.position.tolist()))

        if self.sub is None:
            self.sub = ROS2Subscriber(
                f"/{self.node}/outputs", "sensor_msgs/msg/JointState", on_message, **self.where
            )
            self.pub = ROS2Publisher(f"/{self.node}/actions", "sensor_msgs/msg/JointState", **self.where)
            deadline = time.monotonic() + 30  # an action sent before the route exists is lost
            while not self.pub.pub.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.02)
        with self.lock:
            self.outputs.clear()
        header = get_message_class("std_msgs/msg/Header")
        stamp = get_message_class("builtin_interfaces/msg/Time")
        empty = np.array([], dtype=np.float64)
        for k in range(int(c["n"])):  # lockstep: each action one step, each answered before the next
            self.pub.publish(
                header=header(stamp=stamp(sec=0, nanosec=k), frame_id=""), name=["voltage"],
                position=np.array([float(c["volts"])]), velocity=empty, effort=empty,
            )  # fmt: skip
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                with self.lock:
                    if len(self.outputs) > k:
                        break
                time.sleep(0.005)
        with self.lock:
            names, _ = self.outputs[0]
            return [values[names.index("current")] for _, values in self.outputs]


def installed_hash(srv: str) -> str | None:
    """The service's RIHS01 hash as rosidl wrote it into the installed package (``<Srv>.json``); the
    SDK's own hashing disagrees with rosidl's for the services with nested bounded sequences
    (DescribeParameters: ``floating_point_range`` is ``FloatingPointRange[<=1]``)."""
    package, _, name = srv.split("/")
    path = Path(sys.prefix) / "share" / package / "srv" / f"{name}.json"
    if not path.is_file():
        return None
    hashes = json.loads(path.read_text())["type_hashes"]
    return next(str(h["hash_string"]) for h in hashes if h["type_name"] == srv)


def definitions(srv: str) -> tuple[str | None, str | None]:
    """The request and response text of the installed ``.srv`` file, nested types written in full
    (``rcl_interfaces/msg/Parameter``): the SDK resolves a bare ``Parameter`` under the service's
    own ``srv`` namespace, which has no such type."""
    package, _, name = srv.split("/")
    path = Path(sys.prefix) / "share" / package / "srv" / f"{name}.srv"
    if srv == "std_srvs/srv/Trigger":  # the SDK takes an empty request text for a missing one
        return "\n", "bool success\nstring message\n"
    if package != "rcl_interfaces" or not path.is_file():
        return None, None
    request, response = path.read_text().split("---", 1)

    def qualified(text: str) -> str:
        lines = []
        for line in text.splitlines():
            first = line.split("[")[0].split(" ")[0]
            lines.append(f"{package}/msg/{line}" if first in NESTED else line)
        return "\n".join(lines) + "\n"

    return qualified(request), qualified(response)


def main() -> None:
    peer = Peer(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        command = json.loads(line)
        if command["op"] == "quit":
            break
        try:
            answer = {"ok": getattr(peer, f"op_{command['op']}")(command)}
        except Exception as exc:  # the test reads the reason
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main()
