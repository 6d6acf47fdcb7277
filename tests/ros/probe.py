"""A plain rclpy process that looks at the ROS graph the way any ROS 2 user's node would.

It imports rclpy and message packages only (nothing of fmu-bridge), reads one JSON command per
line on stdin and answers one JSON line on stdout. The tests drive it through ``tests/ros/conftest.py``.
Its domain is ``ROS_DOMAIN_ID`` of its environment.
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
import time
from typing import Any

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

TYPES: dict[str, Any] = {
    "sensor_msgs/msg/JointState": JointState,
    "rosgraph_msgs/msg/Clock": Clock,
    "std_msgs/msg/Float64": Float64,
}


def stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def as_dict(message: Any) -> dict[str, Any]:
    if isinstance(message, JointState):
        return {
            "stamp_ns": stamp_ns(message.header.stamp),
            "name": list(message.name),
            "position": list(message.position),
        }
    if isinstance(message, Clock):
        return {"stamp_ns": stamp_ns(message.clock)}
    if isinstance(message, Float64):
        return {"data": message.data}
    raise TypeError(type(message))


def qos(command: dict[str, Any]) -> QoSProfile:
    reliability = (
        ReliabilityPolicy.BEST_EFFORT
        if command.get("reliability") == "best_effort"
        else ReliabilityPolicy.RELIABLE
    )
    if command.get("keep_all"):
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=reliability)
    return QoSProfile(depth=int(command.get("depth", 10)), reliability=reliability)


class Probe:
    def __init__(self) -> None:
        rclpy.init(args=[])
        self.node = rclpy.create_node("probe")
        self.lock = threading.Lock()
        self.received: dict[str, list[dict[str, Any]]] = {}
        self.subscriptions: dict[str, Any] = {}
        self.publishers: dict[str, Any] = {}
        self.clients: dict[str, Any] = {}
        self.pending: dict[str, Any] = {}
        self.executor = MultiThreadedExecutor(num_threads=2)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self) -> None:
        with contextlib.suppress(ExternalShutdownException):
            self.executor.spin()

    # -- the graph --------------------------------------------------------------------------------
    def op_nodes(self, command: dict[str, Any]) -> Any:
        return [f"{ns.rstrip('/')}/{name}" for name, ns in self.node.get_node_names_and_namespaces()]

    def op_node_info(self, command: dict[str, Any]) -> Any:
        name, ns = command["name"], command.get("namespace", "/")
        return {
            "publishers": dict(self.node.get_publisher_names_and_types_by_node(name, ns)),
            "subscriptions": dict(self.node.get_subscriber_names_and_types_by_node(name, ns)),
            "services": dict(self.node.get_service_names_and_types_by_node(name, ns)),
        }

    def op_topic_info(self, command: dict[str, Any]) -> Any:
        kind = command.get("kind", "publishers")
        getter = (
            self.node.get_publishers_info_by_topic
            if kind == "publishers"
            else self.node.get_subscriptions_info_by_topic
        )
        out = []
        for info in getter(command["topic"]):
            profile = info.qos_profile
            out.append(
                {
                    "node": f"{info.node_namespace.rstrip('/')}/{info.node_name}",
                    "type": info.topic_type,
                    "type_hash": str(info.topic_type_hash),
                    "reliability": profile.reliability.name.lower(),
                    "durability": profile.durability.name.lower(),
                    "history": profile.history.name.lower(),
                    "depth": profile.depth,
                }
            )
        return out

    # -- topics -----------------------------------------------------------------------------------
    def op_subscribe(self, command: dict[str, Any]) -> Any:
        key, topic = command["id"], command["topic"]
        cls = TYPES[command["type"]]
        with self.lock:
            self.received[key] = []

        def on_message(message: Any) -> None:
            entry = {"t": time.monotonic(), **as_dict(message)}
            with self.lock:
                self.received[key].append(entry)

        profile = qos(command)
        if command.get("transient_local"):
            profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
        self.subscriptions[key] = self.node.create_subscription(cls, topic, on_message, profile)
        return True

    def op_wait_count(self, command: dict[str, Any]) -> Any:
        key, count = command["id"], int(command["count"])
        deadline = time.monotonic() + float(command.get("timeout", 20.0))
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.received[key]) >= count:
                    return list(self.received[key])
            time.sleep(0.01)
        with self.lock:
            return {"timeout": True, "messages": list(self.received[key])}

    def op_take(self, command: dict[str, Any]) -> Any:
        with self.lock:
            messages = list(self.received[command["id"]])
            if command.get("clear", True):
                self.received[command["id"]].clear()
        return messages

    def op_wait_subscribers(self, command: dict[str, Any]) -> Any:
        deadline = time.monotonic() + float(command.get("timeout", 20.0))
        while time.monotonic() < deadline:
            if self.node.count_subscribers(command["topic"]) >= int(command.get("count", 1)):
                return True
            time.sleep(0.02)
        return False

    def op_publish(self, command: dict[str, Any]) -> Any:
        topic, type_name = command["topic"], command["type"]
        key = f"{topic}|{type_name}|{command.get('depth', 10)}|{command.get('reliability', 'reliable')}"
        if key not in self.publishers:
            self.publishers[key] = self.node.create_publisher(TYPES[type_name], topic, qos(command))
        publisher = self.publishers[key]
        if command.get("wait_subscribers", True):
            deadline = time.monotonic() + 20.0
            wanted = int(command.get("subscribers", 1))  # /clock: ours and rclpy's TimeSource
            while publisher.get_subscription_count() < wanted and time.monotonic() < deadline:
                time.sleep(0.02)
        for message in command["messages"]:
            publisher.publish(self.message(type_name, message))
        return len(command["messages"])

    @staticmethod
    def message(type_name: str, fields: dict[str, Any]) -> Any:
        if type_name == "sensor_msgs/msg/JointState":
            message = JointState()
            ns = int(fields.get("stamp_ns", 0))
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            message.name = list(fields["name"])
            message.position = [float(v) for v in fields["position"]]
            return message
        if type_name == "rosgraph_msgs/msg/Clock":
            message = Clock()
            message.clock.sec, message.clock.nanosec = divmod(int(fields["stamp_ns"]), 1_000_000_000)
            return message
        if type_name == "std_msgs/msg/Float64":
            return Float64(data=float(fields["data"]))
        raise TypeError(type_name)

    # -- services ---------------------------------------------------------------------------------
    def _client(self, srv: Any, name: str, timeout: float) -> Any:
        """A client of ``name``, kept for the next calls (discovered once)."""
        client = self.clients.get(name)
        if client is None:
            client = self.clients[name] = self.node.create_client(srv, name)
        return client if client.wait_for_service(timeout_sec=timeout) else None

    def _call(self, srv: Any, name: str, request: Any, timeout: float) -> Any:
        future = self._call_async(srv, name, request, timeout)
        return future if isinstance(future, dict) else self._result(future, name, timeout)

    def _call_async(self, srv: Any, name: str, request: Any, timeout: float) -> Any:
        client = self._client(srv, name, timeout)
        if client is None:
            return {"error": f"service {name} not available"}
        return client.call_async(request)

    @staticmethod
    def _result(future: Any, name: str, timeout: float) -> Any:
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.001)
        if not future.done():
            return {"error": f"service {name} did not answer"}
        return future.result()

    def op_client(self, command: dict[str, Any]) -> Any:
        """A Trigger client kept for ``trigger`` (its discovery done here, not in the timed call)."""
        return self._client(Trigger, command["service"], float(command.get("timeout", 20.0))) is not None

    def op_lifecycle_clients(self, command: dict[str, Any]) -> Any:
        """The lifecycle clients of a node, discovered before calls that are timed."""
        timeout = float(command.get("timeout", 20.0))
        return all(
            self._client(srv, f"{command['node']}/{name}", timeout) is not None
            for srv, name in ((GetState, "get_state"), (ChangeState, "change_state"))
        )

    def op_trigger(self, command: dict[str, Any]) -> Any:
        """A Trigger call; ``elapsed_s`` from request to answer, ``t``: when it came (monotonic)."""
        start = time.monotonic()
        answer = self._call(Trigger, command["service"], Trigger.Request(), command.get("timeout", 20.0))
        if isinstance(answer, dict):
            return answer
        end = time.monotonic()
        return {"success": answer.success, "message": answer.message, "elapsed_s": end - start, "t": end}

    def op_lifecycle_get(self, command: dict[str, Any]) -> Any:
        answer = self._call(
            GetState, f"{command['node']}/get_state", GetState.Request(), command.get("timeout", 20.0)
        )
        if isinstance(answer, dict):
            return answer
        return {"id": answer.current_state.id, "label": answer.current_state.label, "t": time.monotonic()}

    TRANSITIONS = {
        "configure": Transition.TRANSITION_CONFIGURE,
        "activate": Transition.TRANSITION_ACTIVATE,
        "deactivate": Transition.TRANSITION_DEACTIVATE,
        "cleanup": Transition.TRANSITION_CLEANUP,
        "shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
        "shutdown_active": Transition.TRANSITION_ACTIVE_SHUTDOWN,
    }

    def op_lifecycle_change(self, command: dict[str, Any]) -> Any:
        self.op_lifecycle_change_async(command)
        answer = self.op_lifecycle_wait(command)
        return {"success": answer["success"]} if "success" in answer else answer

    def op_lifecycle_change_async(self, command: dict[str, Any]) -> Any:
        """Send a change_state request and return at once (``lifecycle_wait`` gets its answer)."""
        request = ChangeState.Request()
        request.transition.id = self.TRANSITIONS[command["transition"]]
        name = f"{command['node']}/change_state"
        future = self._call_async(ChangeState, name, request, command.get("timeout", 30.0))
        self.pending[command["node"]] = future
        return not isinstance(future, dict)

    def op_lifecycle_wait(self, command: dict[str, Any]) -> Any:
        future = self.pending.pop(command["node"])
        if isinstance(future, dict):
            return future
        answer = self._result(future, command["node"], float(command.get("timeout", 30.0)))
        if isinstance(answer, dict):
            return answer
        return {"success": answer.success, "t": time.monotonic()}

    # -- parameters, as ``ros2 param`` reaches them: the node's parameter services ----------------
    def op_param_set(self, command: dict[str, Any]) -> Any:
        value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(command["value"]))
        request = SetParameters.Request(parameters=[Parameter(name=command["name"], value=value)])
        answer = self._call(SetParameters, f"{command['node']}/set_parameters", request, 20.0)
        if isinstance(answer, dict):
            return answer
        return {"successful": answer.results[0].successful, "reason": answer.results[0].reason}

    def op_param_get(self, command: dict[str, Any]) -> Any:
        request = GetParameters.Request(names=[command["name"]])
        answer = self._call(GetParameters, f"{command['node']}/get_parameters", request, 20.0)
        return answer if isinstance(answer, dict) else answer.values[0].double_value

    def op_param_describe(self, command: dict[str, Any]) -> Any:
        request = DescribeParameters.Request(names=[command["name"]])
        answer = self._call(DescribeParameters, f"{command['node']}/describe_parameters", request, 20.0)
        if isinstance(answer, dict):
            return answer
        descriptor = answer.descriptors[0]
        ranges = [(r.from_value, r.to_value) for r in descriptor.floating_point_range]
        return {"type": descriptor.type, "description": descriptor.description, "ranges": ranges}

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def main() -> None:
    probe = Probe()
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        command = json.loads(line)
        if command["op"] == "quit":
            break
        try:
            result: Any = getattr(probe, f"op_{command['op']}")(command)
            answer = {"ok": result}
        except Exception as exc:
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(answer), flush=True)
    probe.close()


if __name__ == "__main__":
    main()
