"""A deployed agent as a managed (lifecycle) ROS 2 node: ``agent run RUN --transport rclpy --managed``.

The node starts unconfigured and answers the usual lifecycle services (``~/change_state``,
``~/get_state``, ``~/get_available_transitions``, ...), as ``ros2 lifecycle`` and launch_ros's
lifecycle events drive them:

- **configure** reads its settings from ROS parameters, loads the policy (torch, ONNX or the policy
  FMU) and checks the observation mapping: every observation the agent was trained on must be
  among the joint names the robot publishes (``observation_names``; empty: the training names),
  and the run must match the experiment. A failure leaves it unconfigured with the reason in its log.
- **activate** starts acting: each observation message gets one action.
- **deactivate** stops acting; with ``missing: safe`` it publishes the safe action once, with
  ``hold`` it publishes nothing (the plant holds the last action).
- **cleanup** drops the policy and the topics; **shutdown** ends the node: once ``finalized`` the
  process exits.

Every other way out of active fails safe: **shutdown** from active, Ctrl-C (SIGINT), SIGTERM and an
error (a transition that fails, or an exception while acting) stop acting first and then publish
the safe action (``safe_value``, 0 by default), whatever ``missing`` says: the node is going away
and holds nothing, so the safe action is the last action it sends. An error while acting also
deactivates the node (it says so in its log and in the transition event).

The lifecycle services are served beside the transitions (a reentrant callback group on a
multi-threaded executor): ``configure`` loads the policy (seconds: torch, onnxruntime) without
holding up ``get_state``, ``get_available_states`` and ``get_available_transitions``, which answer
at once (``configuring`` meanwhile). Transitions themselves run one at a time: a ``change_state``
that arrives while another is under way is refused (``success: false``, logged).

Parameters: ``runtime`` (torch, onnx, fmu), ``missing`` (hold, safe), ``safe_value`` (one per action
input, or one for all), ``timeout`` (s without an observation before the missing rule, while
active), ``observation_topic``, ``action_topic``, ``observation_names``.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
from agents.policies import load_policy
from bridge.errors import BridgeError, ConfigError
from bridge.experiment.validate import check_experiment
from bridge.net.ros2 import cdr

_log = logging.getLogger(__name__)
JOINT_STATE = "sensor_msgs/msg/JointState"


def _like(default: Any, value: Any, name: str) -> Any:
    """A ``-p NAME:=VALUE`` value in the declared parameter's type (``2`` for a double is ``2.0``)."""
    try:
        if isinstance(default, list):
            values = value if isinstance(value, list) else [value]
            return [float(v) for v in values] if isinstance(default[0], float) else [str(v) for v in values]
        return float(value) if isinstance(default, float) else str(value)
    except (TypeError, ValueError):
        raise ConfigError(f"--ros-args -p {name}:={value!r}: expected the type of {default!r}") from None


class ManagedAgent:
    """The lifecycle node and what its transitions build; ``close()`` ends it."""

    def __init__(self, model: Path, config: Path | None, settings: DeploySettings) -> None:
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.lifecycle import LifecycleNodeMixin, TransitionCallbackReturn
        from rclpy.node import Node

        from bridge.net.ros2.args import current as ros_args
        from bridge.net.ros2.rclpy_backend import RclpyNode
        from bridge.net.ros2.rclpy_lifecycle import one_transition_at_a_time
        from bridge.net.ros2.view import ros_node_name

        self.model, self.config, self.base = model, config, settings
        self.experiment, _ = deployment_experiment(model, config)
        self._ok, self._failure = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
        self._transitions = threading.Lock()
        self.finished = threading.Event()  # finalized and the caller answered: the process may exit
        self._finalized = False
        outer = self

        class _Node(LifecycleNodeMixin, Node):  # type: ignore[misc]  # rclpy is untyped here
            def __init__(self, node_name: str, **kwargs: Any) -> None:
                Node.__init__(self, node_name, **kwargs)
                LifecycleNodeMixin.__init__(self, callback_group=ReentrantCallbackGroup())
                one_transition_at_a_time(self, outer._transitions, outer._answered)

            def on_configure(self, state: Any) -> Any:
                return outer._configure()

            def on_activate(self, state: Any) -> Any:
                return outer._activate()

            def on_deactivate(self, state: Any) -> Any:
                return outer._deactivate()

            def on_cleanup(self, state: Any) -> Any:
                return outer._cleanup()

            def on_shutdown(self, state: Any) -> Any:
                return outer._shutdown()

            def on_error(self, state: Any) -> Any:
                return outer._error()

        declared = {
            "runtime": settings.runtime,
            "missing": settings.missing,
            "safe_value": [float(v) for v in settings.safe_inputs or [0.0]],
            "timeout": float(settings.timeout_s),
            "observation_topic": settings.observation_topic or self._node_topic("outputs"),
            "action_topic": settings.action_topic or self._node_topic("actions"),
            "observation_names": list(self.experiment.observations.outputs) or [""],
        }
        given = {k: _like(declared[k], v, k) for k, v in ros_args().parameters.items() if k in declared}
        self.ros = RclpyNode(
            f"{ros_node_name(settings.node)}_agent",
            settings.namespace,
            domain_id=settings.domain_id,
            node_class=_Node,
            executor_threads=3,  # transitions, the other lifecycle services, observations
        )
        for name, default in declared.items():
            self.ros.node.declare_parameter(name, given.get(name, default))
        self.agent: DeployedAgent | None = None
        self._policy: Any = None
        self._info: Any = None
        self._publisher: Any = None
        self._subscription: Any = None
        self._layout: Any = None
        self._lock = threading.Lock()
        self._last_stamp = -1
        self._episode = 0

    def _node_topic(self, topic: str) -> str:
        from bridge.net.ros2.names import normalize_namespace
        from bridge.net.ros2.view import ros_node_name

        namespace = normalize_namespace(self.base.namespace).rstrip("/")
        return f"{namespace}/{ros_node_name(self.base.node)}/{topic}"

    def _param(self, name: str) -> Any:
        return self.ros.node.get_parameter(name).value

    # -- transitions ----------------------------------------------------------------------------------
    def _configure(self) -> Any:
        try:
            self.settings = self._settings()
            self._policy = load_policy(self.model, self.settings.runtime)
            run_dir = self.model if self.model.is_dir() else self.model.parent
            self._info = model_info_for(self.experiment, run_dir, None)
            check_experiment(self.experiment, self._info)
            wanted = list(self.experiment.observations.outputs)
            published = [n for n in self._param("observation_names") if n]
            missing = [n for n in wanted if n not in published]
            if missing:
                raise ConfigError(
                    f"observation mapping: the agent observes {wanted}, the robot publishes {published}: "
                    f"{missing} missing; set the parameter observation_names, or remap the topic"
                )
        except BridgeError as exc:
            self.ros.node.get_logger().error(f"configure failed: {exc}")
            self._policy = None
            return self._failure
        names = list(self.experiment.actions.inputs)
        self._layout = cdr.JointStateLayout.of(names)
        self._publisher = self.ros.create_publisher(self.settings.action_topic or "", JOINT_STATE)
        self._subscription = self.ros.create_subscription(
            self.settings.observation_topic or "", JOINT_STATE, self._on_joint_state
        )
        self.ros.node.get_logger().info(
            f"configured: {self.settings.runtime} policy of {self.model}, observing "
            f"{self.settings.observation_topic}, acting on {self.settings.action_topic}"
        )
        return self._ok

    def _settings(self) -> DeploySettings:
        runtime, missing = str(self._param("runtime")), str(self._param("missing"))
        if runtime not in ("torch", "onnx", "fmu") or missing not in ("hold", "safe"):
            raise ConfigError(
                f"parameters: runtime {runtime!r} (torch, onnx, fmu), missing {missing!r} (hold, safe)"
            )
        n = len(self.experiment.actions.inputs)
        safe = [float(v) for v in self._param("safe_value")]
        if len(safe) not in (1, n):
            raise ConfigError(f"parameter safe_value: {len(safe)} values for {n} action inputs")
        return DeploySettings(
            transport="rclpy",
            node=self.base.node,
            observation_topic=str(self._param("observation_topic")),
            action_topic=str(self._param("action_topic")),
            missing=missing,  # type: ignore[arg-type]  # checked above
            safe_inputs=safe * n if len(safe) == 1 else safe,
            timeout_s=float(self._param("timeout")),
            domain_id=self.base.domain_id,
            namespace=self.base.namespace,
            runtime=runtime,  # type: ignore[arg-type]  # checked above
            scenario=self.base.scenario,
        )

    def _activate(self) -> Any:
        agent = DeployedAgent(self._policy, self.experiment, self._info, self.settings, self._publish)
        with self._lock:
            self.agent = agent
        self.ros.node.get_logger().info("active: acting on each observation")
        return self._ok

    def _deactivate(self) -> Any:
        with self._lock:
            agent, self.agent = self.agent, None
        if agent is not None:
            agent.close()
        if self.settings.missing == "safe" and self.settings.safe_inputs is not None:
            self._publish(list(self.settings.safe_inputs), 0)
            self.ros.node.get_logger().info(f"inactive: safe action {self.settings.safe_inputs} sent")
        else:
            self.ros.node.get_logger().info("inactive: holding (no action sent)")
        return self._ok

    def _exit_safe(self, why: str) -> None:
        """Leave active for good (shutdown, a signal, an error): stop acting, then send the safe
        action, so that it is the last action sent; nothing when the node is not active."""
        with self._lock:
            agent, self.agent = self.agent, None
        if agent is None:
            return
        agent.close()  # no action of the policy or its missing rule after this
        safe = list(self.settings.safe_inputs or [0.0] * len(self.experiment.actions.inputs))
        self._publish(safe, 0)
        self.ros.node.get_logger().warning(f"left active ({why}): safe action {safe} sent")

    def _shutdown(self) -> Any:
        self._exit_safe("shutdown")
        self._cleanup()
        self._finalized = True  # the process ends once the caller has its answer (_answered)
        self.ros.node.get_logger().info("finalized: the process ends")
        return self._ok

    def _answered(self) -> None:
        """A change_state response went out: after the shutdown's, the process may end."""
        if self._finalized:
            self.finished.set()

    def _error(self) -> Any:
        self._exit_safe("a transition failed")
        self._cleanup()
        return self._ok  # back to unconfigured

    def _failed_while_acting(self, exc: Exception) -> None:
        """An exception while acting: fail safe and deactivate (one transition at a time)."""
        self.ros.node.get_logger().error(f"acting failed ({type(exc).__name__}: {exc}); deactivating")
        self._exit_safe(f"error: {type(exc).__name__}")
        if self._transitions.acquire(blocking=False):
            try:
                self.ros.node.trigger_deactivate()
            except Exception:  # not active any more (a transition got there first)
                _log.debug("deactivate after an error", exc_info=True)
            finally:
                self._transitions.release()

    def _cleanup(self) -> Any:
        with self._lock:
            agent, self.agent = self.agent, None
        if agent is not None:
            agent.close()
        policy_close = getattr(self._policy, "close", None)  # a policy FMU frees its instance
        if policy_close is not None:
            policy_close()
        for entity, destroy in (
            (self._subscription, self.ros.node.destroy_subscription),
            (getattr(self._publisher, "_publisher", None), self.ros.node.destroy_publisher),
        ):
            if entity is not None:
                destroy(entity)
        self._publisher = self._subscription = self._policy = None
        return self._ok

    # -- data ---------------------------------------------------------------------------------------------
    def _publish(self, inputs: list[float], step: int) -> None:
        if self._publisher is None:
            return
        stamp = self._last_stamp if self._last_stamp >= 0 else time.time_ns()
        names = self.experiment.actions.inputs
        self._publisher.publish(self._layout.pack(stamp, inputs[: len(names)]))

    def _on_joint_state(self, payload: bytes, info: Any) -> None:
        with self._lock:
            agent = self.agent
        if agent is None:  # configured but not active: observations are not acted on
            return
        try:
            message = cdr.decode_joint_state(payload)
        except Exception as exc:  # a foreign or malformed message: not an observation
            _log.warning("dropped an observation message that is not a JointState: %s", exc)
            return
        index = {name: i for i, name in enumerate(message.name)}
        try:
            outputs = [float(message.position[index[n]]) for n in agent.task.output_names]
        except (KeyError, IndexError):
            _log.warning(
                "observation message lacks %s (it has names %s, %d positions)",
                [n for n in agent.task.output_names if n not in index],
                message.name,
                len(message.position),
            )
            return
        if message.stamp_ns < self._last_stamp:
            self._episode += 1
        self._last_stamp = message.stamp_ns
        try:
            agent.observe(outputs, episode=self._episode)
        except Exception as exc:  # the policy or the transport failed: never act on after it
            self._failed_while_acting(exc)

    @property
    def state(self) -> str:
        return "active" if self.agent is not None else "configured" if self._policy is not None else "idle"

    def run(self, duration_s: float | None, stop: threading.Event) -> Any:
        """Until ``stop``, Ctrl-C/SIGTERM, ``duration_s`` or the shutdown transition (finalized)."""
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while not stop.wait(0.1) and not self.finished.is_set():
                if deadline is not None and time.monotonic() > deadline:
                    break
        except KeyboardInterrupt:
            pass
        from agents.deploy import Stats

        agent = self.agent
        return agent.stats if agent is not None else Stats()

    def close(self) -> None:
        """Ctrl-C, SIGTERM, the end of ``--duration``: fail safe if active, then end the node."""
        self._exit_safe("the process is stopping")
        self._cleanup()
        self.ros.close()
