"""The same node interface as ``bridge.net.ros2.RosNode``, on rclpy (a ROS 2 install, any RMW).

Payloads stay CDR bytes on both sides: rclpy publishes serialized messages as they are and
hands raw subscriptions the bytes, so the code above (the FMU node's ROS view, the deployed
agent) runs unchanged on either backend. Only this module imports rclpy.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from bridge.errors import DependencyMissing

_log = logging.getLogger(__name__)
_INIT_LOCK = threading.Lock()


def _rclpy() -> Any:
    try:
        import rclpy
    except ImportError as exc:
        raise DependencyMissing(
            "rclpy",
            "the rclpy backend",
            "source a ROS 2 Jazzy installation (source /opt/ros/jazzy/setup.bash) in this shell, "
            "or use the zenoh backend, which needs no ROS install",
        ) from exc
    with _INIT_LOCK:
        if not rclpy.ok():
            rclpy.init()
    return rclpy


def _message_class(type_name: str) -> Any:
    from rosidl_runtime_py.utilities import get_message, get_service

    return get_service(type_name) if "/srv/" in type_name else get_message(type_name)


def _qos(settings: Any) -> Any:
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    reliability = getattr(settings, "reliability", "reliable")
    policy = ReliabilityPolicy.BEST_EFFORT if reliability == "best_effort" else ReliabilityPolicy.RELIABLE
    return QoSProfile(depth=int(getattr(settings, "depth", 10)), reliability=policy)


class _Publisher:
    def __init__(self, publisher: Any) -> None:
        self._publisher = publisher

    def publish(self, payload: bytes) -> None:
        self._publisher.publish(payload)  # rclpy publishes bytes as an already serialized message


class RclpyNode:
    """A real rclpy node, spun on its own executor thread; ``close()`` shuts it down."""

    def __init__(self, name: str, namespace: str = "/", *, domain_id: int | None = None) -> None:
        rclpy = _rclpy()
        from rclpy.executors import SingleThreadedExecutor

        if domain_id is not None:
            _log.info("rclpy uses ROS_DOMAIN_ID from the environment; domain %d is ignored here", domain_id)
        self.node = rclpy.create_node(name, namespace=namespace)
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._executor.spin, name=f"rclpy-{name}", daemon=True)
        self._thread.start()

    def create_publisher(self, topic: str, type_name: str, qos: Any = None) -> _Publisher:
        return _Publisher(self.node.create_publisher(_message_class(type_name), topic, _qos(qos)))

    def create_subscription(
        self, topic: str, type_name: str, callback: Callable[[bytes, Any], None], qos: Any = None
    ) -> Any:
        return self.node.create_subscription(
            _message_class(type_name), topic, lambda data: callback(bytes(data), None), _qos(qos), raw=True
        )

    def create_service(
        self, name: str, srv_type: str, handler: Callable[[bytes], bytes], qos: Any = None
    ) -> Any:
        from rclpy.serialization import deserialize_message, serialize_message

        cls = _message_class(srv_type)

        def serve(request: Any, response: Any) -> Any:
            answer = handler(serialize_message(request))
            return deserialize_message(answer, cls.Response)

        return self.node.create_service(cls, name, serve)

    def close(self) -> None:
        self._executor.shutdown()
        self.node.destroy_node()
