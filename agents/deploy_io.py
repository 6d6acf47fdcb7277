"""Wiring a DeployedAgent to its transport: native Zenoh frames, or the ROS 2 view (rmw_zenoh or rclpy)."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any, Literal

from agents.deploy import DeployedAgent, DeploySettings, Stats, deployment_experiment, model_info_for
from agents.policies import load_policy
from bridge.errors import TransportError
from bridge.net import protocol as proto
from bridge.net.deadlines import Deadlines, node_deadline_s
from bridge.net.ros2 import cdr
from bridge.net.transport import ZenohOptions, open_session, undeclare

_log = logging.getLogger(__name__)


def _lockstep(description: dict[str, Any] | None, timeout_s: float) -> Deadlines | None:
    """The deadlines of a lockstep node (None: a real-time node, or a ROS source): ``--timeout``
    is their floor, the node's own deadline and the slowest step measured extend them."""
    if description is None or description.get("mode") != "lockstep":
        return None
    return Deadlines(timeout_s, node_deadline_s(description))


class AgentNode:
    """A deployed agent with its subscriptions and publishers; ``close()`` stops everything."""

    def __init__(
        self,
        model: Path,
        config: Path | None,
        settings: DeploySettings,
        options: ZenohOptions | None = None,
        session: Any = None,
    ) -> None:
        self.settings = settings
        # rclpy needs no Zenoh session (and so no router): it speaks the machine's RMW
        self._own = session is None and settings.transport != "rclpy"
        self._session = open_session(options) if self._own else session
        self._declared: list[Any] = []
        self._ros: Any = None  # the ROS node (ros2/rclpy transports), made by _ros_publisher
        experiment, _ = deployment_experiment(model, config)
        policy = load_policy(model, settings.runtime, experiment)
        description = self._node_description() if settings.transport == "zenoh" else None
        run_dir = model if model.is_dir() else model.parent
        info = model_info_for(experiment, run_dir, description)
        publish = (
            self._zenoh_publisher() if settings.transport == "zenoh" else self._ros_publisher(experiment)
        )
        lockstep = _lockstep(description, settings.timeout_s)
        self.agent = DeployedAgent(policy, experiment, info, settings, publish, lockstep=lockstep)
        if description is not None and description["output_names"] != list(self.agent.task.output_names):
            raise TransportError(
                f"node {settings.node!r} publishes {description['output_names']}, the agent "
                f"observes {list(self.agent.task.output_names)}: start it with the same experiment"
            )
        if settings.transport == "zenoh":
            keys = proto.Keys(settings.prefix, settings.node)
            self._declared.append(self._session.declare_subscriber(keys.outputs, self._on_frame))
        else:
            topic = settings.observation_topic or self._node_topic("outputs")
            ros: Any = self._ros  # created by _ros_publisher above
            ros.create_subscription(topic, "sensor_msgs/msg/JointState", self._on_joint_state)
        self._episode = 0
        self._last_stamp = -1

    # -- native Zenoh -------------------------------------------------------------------------------
    def _node_description(self) -> dict[str, Any]:
        from bridge.net.remote import NodeClient

        client = NodeClient(self._session, self.settings.node, prefix=self.settings.prefix, timeout_s=5.0)
        description = client.description
        client.close()
        return description

    def _zenoh_publisher(self) -> Any:
        keys = proto.Keys(self.settings.prefix, self.settings.node)
        pub = self._session.declare_publisher(keys.actions)
        self._declared.append(pub)
        state = {"episode": 0}

        def publish(inputs: list[float], step: int) -> None:
            pub.put(proto.encode_values(proto.ACTION, state["episode"], step + 1, 0, inputs))

        self._frame_state = state
        return publish

    def _on_frame(self, sample: Any) -> None:
        try:
            frame = proto.decode(sample.payload.to_bytes())
        except TransportError:
            return
        if frame.kind != proto.OUTPUTS:
            return
        self._frame_state["episode"] = frame.episode
        self.agent.observe(frame.values.tolist(), episode=frame.episode, step=frame.step)

    # -- ROS 2 view ----------------------------------------------------------------------------------
    def _ros_publisher(self, experiment: Any) -> Any:
        from bridge.net.ros2.view import RosViewSettings, open_backend_node, qos_profile, ros_node_name

        backend: Literal["zenoh", "rclpy"] = "rclpy" if self.settings.transport == "rclpy" else "zenoh"
        view = RosViewSettings(
            domain_id=self.settings.domain_id, namespace=self.settings.namespace, backend=backend
        )
        self._ros = open_backend_node(self._session, view, f"{ros_node_name(self.settings.node)}_agent")
        topic = self.settings.action_topic or self._node_topic("actions")
        publisher = self._ros.create_publisher(topic, "sensor_msgs/msg/JointState", qos_profile(view))
        names = list(experiment.actions.inputs)
        layout = cdr.JointStateLayout.of(names)

        def publish(inputs: list[float], step: int) -> None:
            # stamped with the observation it answers (a robot's clock, or the FMU's simulation time)
            stamp = self._last_stamp if self._last_stamp >= 0 else time.time_ns()
            publisher.publish(layout.pack(stamp, inputs[: len(names)]))

        return publish

    def _node_topic(self, topic: str) -> str:
        """``/<namespace>/<node>/<topic>``, named as the FMU node is served (``worker-1`` -> ``worker_1``)."""
        from bridge.net.ros2.names import normalize_namespace
        from bridge.net.ros2.view import ros_node_name

        namespace = normalize_namespace(self.settings.namespace).rstrip("/")
        return f"{namespace}/{ros_node_name(self.settings.node)}/{topic}"

    def _on_joint_state(self, payload: bytes, info: Any) -> None:
        message = cdr.decode_joint_state(payload)
        index = {name: i for i, name in enumerate(message.name)}
        try:
            outputs = [float(message.position[index[n]]) for n in self.agent.task.output_names]
        except KeyError as exc:
            _log.warning("observation message lacks %s (it has %s)", exc, message.name)
            return
        if message.stamp_ns < self._last_stamp:  # simulation time went back: a new episode
            self._episode += 1
        self._last_stamp = message.stamp_ns
        self.agent.observe(outputs, episode=self._episode)

    def run(self, duration_s: float | None = None, stop: threading.Event | None = None) -> Stats:
        stop = stop or threading.Event()
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while not stop.wait(0.1):
                if deadline is not None and time.monotonic() > deadline:
                    break
        except KeyboardInterrupt:
            pass
        return self.agent.stats

    def close(self) -> None:
        self.agent.close()  # first: callbacks that still arrive find a stopped agent
        policy_close = getattr(self.agent.policy, "close", None)  # a policy FMU frees its instance
        if policy_close is not None:
            policy_close()
        for entity in reversed(self._declared):
            undeclare(entity)
        if self._ros is not None:
            self._ros.close()
        if self._own and self._session is not None:
            self._session.close()
