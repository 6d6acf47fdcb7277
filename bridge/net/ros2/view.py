"""The ROS 2 view of an FMU node: what ``ros2 topic echo`` and ``ros2 service call`` see.

Over rmw_zenoh's wire format (``bridge.net.ros2``, no ROS install) or, where ``rclpy`` imports,
through rclpy with any RMW. Topics of node ``<name>`` in ``<namespace>``:

- ``~/outputs``: ``sensor_msgs/msg/JointState``, one per sample: names = the FMU outputs, position =
  their values, header.stamp = simulation time;
- ``~/actions``: ``sensor_msgs/msg/JointState`` in: names = FMU inputs (any subset), position =
  values; held (real time) or one sample per message (lockstep). In lockstep no message may be
  dropped: the subscription keeps all (KEEP_ALL, reliable), so messages that arrive while a step
  runs wait for it instead of being overwritten as with KEEP_LAST 10; a message the RMW reports
  lost (rclpy's ``message_lost`` event) is counted in ``lost`` and logged as a warning. A
  publisher keeps its side of the contract with RELIABLE and a depth of at least the steps it
  sends ahead of the outputs (one, if it waits for each output);
- ``/clock``: ``rosgraph_msgs/msg/Clock`` in real-time mode (simulation time); with
  ``follow_clock`` subscribed instead, with ROS's clock QoS (:func:`clock_qos`);
- ``~/reset``: ``std_srvs/srv/Trigger``: back to t0 with the experiment's nominal values;
- with ``per_variable``: ``std_msgs/msg/Float64`` on ``~/out/<output>`` and ``~/in/<input>``, the
  way fmi_adapter users know them;
- the FMU parameters a reset may set as ROS parameters (``bridge.net.ros2.params``; rclpy's own
  parameter services, or on the zenoh backend ``bridge.net.ros2.param_services``): set between
  episodes, applied at the next ``~/reset``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from bridge.errors import ConfigError
from bridge.experiment.sections import RosSection
from bridge.net.ros2 import cdr
from bridge.net.ros2.clock import ClockFollower

RosViewSettings = RosSection  # the ``ros:`` section of an experiment

_log = logging.getLogger(__name__)


def settings_from(section: dict[str, Any], *, backend: str | None = None) -> RosViewSettings:
    from pydantic import ValidationError

    from bridge.experiment.config import format_validation_error

    data = {**section, **({"backend": backend} if backend else {})}
    try:
        return RosViewSettings.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, None, "ros.")) from None


def ros_node_name(name: str) -> str:
    """A valid ROS node name from an fmu-bridge node name (``worker-1`` -> ``worker_1``)."""
    from bridge.net.ros2.names import name_token

    return name_token(name)


def open_backend_node(session: Any, settings: RosViewSettings, name: str) -> Any:
    """A node with ``create_publisher/create_subscription/create_service/close`` taking CDR bytes."""
    if settings.backend == "rclpy":
        from bridge.net.ros2.rclpy_backend import RclpyNode

        return RclpyNode(
            name, settings.namespace, domain_id=settings.domain_id, use_sim_time=settings.follow_clock
        )
    if session is None:
        raise ConfigError("the zenoh ROS backend needs a Zenoh session; use the rclpy backend without one")
    from bridge.net.ros2 import RosContext

    context = RosContext(session, domain_id=settings.domain_id, namespace=settings.namespace)
    return context.create_node(name)


def clock_qos(settings: RosViewSettings) -> Any:
    """ROS's clock QoS for following ``/clock``: best effort, depth 1 (rclpy's ``TimeSource``).

    A best-effort subscription matches every ``/clock`` publisher, reliable ones and the best-effort
    ones of rosbag2's player and Gazebo; depth 1: only the newest time matters."""
    if settings.backend == "rclpy":
        from bridge.net.ros2.rclpy_backend import RclpyQoS

        return RclpyQoS("best_effort", 1)
    from bridge.net.ros2 import QoS, Reliability

    return QoS(reliability=Reliability.BEST_EFFORT, depth=1)


def qos_profile(settings: RosViewSettings, *, keep_all: bool = False) -> Any:
    """The endpoints' QoS for the backend; ``keep_all`` where no message may be overwritten."""
    if settings.backend == "rclpy":
        from bridge.net.ros2.rclpy_backend import RclpyQoS

        return RclpyQoS(settings.reliability, settings.depth, keep_all)
    from bridge.net.ros2 import History, QoS, Reliability

    reliability = Reliability.RELIABLE if settings.reliability == "reliable" else Reliability.BEST_EFFORT
    history = History.KEEP_ALL if keep_all else History.KEEP_LAST
    return QoS(reliability=reliability, history=history, depth=settings.depth)


class RosView:
    """Publishes a node's samples as ROS messages and feeds ROS actions and resets back to it."""

    def __init__(
        self,
        session: Any,
        settings: RosViewSettings,
        *,
        name: str,
        output_names: Sequence[str],
        input_names: Sequence[str],
        on_actions: Callable[[dict[str, float]], None],
        on_reset: Callable[[], tuple[bool, str]],
        realtime: bool,
        follower: ClockFollower | None = None,
        parameters: Sequence[Any] = (),
        on_parameters: Callable[[dict[str, Any]], str | None] | None = None,
        node: Any = None,
    ) -> None:
        self.settings = settings
        self._output_names, self._input_names = tuple(output_names), tuple(input_names)
        self._layout = cdr.JointStateLayout.of(list(output_names))
        self._on_actions, self._on_reset = on_actions, on_reset
        # ``node``: a node of someone else's to serve on (the managed FMU node's lifecycle node)
        self.node = node or open_backend_node(session, settings, ros_node_name(settings.node_name or name))
        qos = qos_profile(settings)
        self._outputs = self.node.create_publisher(settings.outputs_topic, "sensor_msgs/msg/JointState", qos)
        self.dropped = 0  # malformed or foreign messages
        self.lost = 0  # messages the RMW reported lost before they reached us
        if settings.backend == "rclpy":  # lockstep: KEEP_ALL, no message overwritten while a step runs
            self.node.create_subscription(
                settings.actions_topic,
                "sensor_msgs/msg/JointState",
                self._actions,
                qos if realtime else qos_profile(settings, keep_all=True),
                on_lost=self._on_lost,
            )
        else:  # Zenoh hands each message to the callback in turn: nothing is overwritten
            self.node.create_subscription(
                settings.actions_topic, "sensor_msgs/msg/JointState", self._actions, qos
            )
        self.node.create_service(settings.reset_service, "std_srvs/srv/Trigger", self._reset)
        self.follower = follower
        self._clock = (
            self.node.create_publisher("/clock", "rosgraph_msgs/msg/Clock", qos)
            if (realtime and settings.clock and follower is None)
            else None
        )
        if follower is not None:  # another simulator's clock drives this node (bridge.net.ros2.clock)
            self.node.create_subscription(
                "/clock", "rosgraph_msgs/msg/Clock", self._on_clock, clock_qos(settings)
            )
        self._per_variable: list[Any] = []
        if settings.per_variable:
            self._declare_per_variable(qos)
        if parameters and on_parameters is not None:  # params.py: rclpy's own services, or ours
            if settings.backend == "rclpy":
                self.node.declare_fmu_parameters(list(parameters), on_parameters)
            else:
                from bridge.net.ros2.param_services import ParameterServices

                ParameterServices(self.node, parameters, on_parameters)

    def _on_lost(self, count: int) -> None:
        self.lost += count
        _log.warning(
            "ROS actions: the RMW lost %d message(s) (%d in all): in lockstep each one was a step; "
            "publish with RELIABLE and a larger depth, or wait for each output before the next action",
            count,
            self.lost,
        )

    def _declare_per_variable(self, qos: Any) -> None:
        from bridge.net.ros2.names import name_token

        self._per_variable = [
            self.node.create_publisher(f"~/out/{name_token(n)}", "std_msgs/msg/Float64", qos)
            for n in self._output_names
        ]
        for name in self._input_names:

            def on_value(payload: bytes, info: Any, name: str = name) -> None:
                self._on_actions({name: cdr.decode_float64(payload)})

            self.node.create_subscription(f"~/in/{name_token(name)}", "std_msgs/msg/Float64", on_value, qos)

    def _on_clock(self, payload: bytes, info: Any) -> None:
        try:
            clock_ns = cdr.decode_clock(payload)
        except ValueError as exc:
            self.dropped += 1
            _log.warning("/clock: dropped a message that is not a Clock: %s", exc)
            return
        try:
            if self.follower is not None:
                self.follower.tick(clock_ns)
        except Exception:  # never let a subscription handler die
            _log.exception("/clock: could not follow the tick at %d ns", clock_ns)

    def publish(self, sim_time_ns: int, outputs: Sequence[float]) -> None:
        """One sample: the bundled outputs, per-variable values, the clock."""
        follower = self.follower
        if follower is not None and follower.origin_ns is not None:  # stamped in the clock's time
            sim_time_ns += follower.origin_ns - follower.t0_ns
        self._outputs.publish(self._layout.pack(sim_time_ns, outputs))
        for publisher, value in zip(self._per_variable, outputs):
            publisher.publish(cdr.encode_float64(float(value)))
        if self._clock is not None:
            self._clock.publish(cdr.encode_clock(sim_time_ns))

    def _actions(self, payload: bytes, info: Any) -> None:
        try:
            message = cdr.decode_joint_state(payload)
        except Exception as exc:  # a foreign or malformed message: count and carry on
            self.dropped += 1
            _log.warning("ROS actions: dropped a message that is not a JointState: %s", exc)
            return
        if len(message.name) != len(message.position):
            self.dropped += 1
            _log.warning("ROS actions: %d names but %d positions", len(message.name), len(message.position))
            return
        known = {n: float(v) for n, v in zip(message.name, message.position) if n in self._input_names}
        unknown = [n for n in message.name if n not in self._input_names]
        if unknown:
            _log.warning(
                "ROS actions: %s are not inputs of this node (inputs: %s)", unknown, self._input_names
            )
        if known:
            try:
                self._on_actions(known)
            except Exception:  # never let a subscription handler die
                _log.exception("ROS actions: could not apply %s", known)

    def _reset(self, request: bytes) -> bytes:
        from bridge.net.ros2 import interfaces

        if len(request) > 64:  # a Trigger request is empty: 4 bytes of CDR header and padding
            self.dropped += 1
            return interfaces.trigger_response(
                False, f"bad request: std_srvs/srv/Trigger takes no fields, got {len(request)} bytes"
            )
        if self.follower is not None:  # first: no step of the clock's catch-up beside the reset
            self.follower.restart()  # lined up with the clock again at its next tick
        try:
            success, message = self._on_reset()
        except Exception as exc:  # never let a service handler die
            _log.exception("ROS reset failed")
            success, message = False, f"reset failed ({type(exc).__name__})"

        return interfaces.trigger_response(success, message)

    def close(self) -> None:
        if self.follower is not None:  # first: no step after the node's entities are gone
            self.follower.close()
        self.node.close()
