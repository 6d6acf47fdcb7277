"""Managed (lifecycle) nodes on rclpy: the FMU node (``fmu-bridge node --managed``) and what the
managed agent (``agents.deploy_lifecycle``) shares with it. An rclpy adapter module, like
``rclpy_backend``.

The lifecycle services sit in a reentrant callback group on a multi-threaded executor, so that
``get_state`` and the other queries answer while a transition runs (``configure`` loads an FMU or
a policy: seconds); transitions run one at a time (:func:`one_transition_at_a_time`).

The managed FMU node (:class:`ManagedFmuNode`) is the FMU node's own ROS node (``/<name>``, its
outputs, actions, reset and parameters beside the lifecycle services):

- **configure** loads the FMU and declares the node (its Zenoh keys, its ROS view) without
  stepping; a failure leaves it unconfigured with the reason in its log;
- **activate** starts stepping: a real-time node resets and runs on its clock, a lockstep node
  takes ROS actions (refused while inactive: ``ros_rejected_inactive``);
- **deactivate** stops stepping (a real-time node's clock stops; the FMU keeps its state);
- **cleanup** closes the FMU and its topics, services and parameters; **shutdown** too, and the
  process ends once ``finalized``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from bridge.errors import BridgeError
from bridge.net.ros2.rclpy_backend import RclpyNode

_log = logging.getLogger(__name__)


def one_transition_at_a_time(
    node: Any, lock: threading.Lock, answered: Callable[[], None] | None = None
) -> None:
    """``change_state`` (in a reentrant group) refuses a transition while another runs: rcl's state
    machine would raise inside the executor on a transition from a transition state.

    ``answered()`` runs once each ``change_state`` response has been sent: an owner whose node is
    finalized lets the process end only then (rclpy's executor shutdown does not wait for a callback
    under way, so an exit straight from ``on_shutdown`` lost the caller's answer)."""
    service = node._service_change_state  # rclpy's own service of the lifecycle mixin
    change = service.callback
    if answered is not None:
        send = service.send_response

        def send_then_tell(response: Any, header: Any) -> None:
            try:
                send(response, header)
            finally:
                answered()

        service.send_response = send_then_tell

    def serialized(request: Any, response: Any) -> Any:
        if not lock.acquire(blocking=False):
            node.get_logger().warning(
                f"change_state {request.transition.id} refused: another transition is under way"
            )
            response.success = False
            return response
        try:
            return change(request, response)
        finally:
            lock.release()

    service.callback = serialized


def lifecycle_class(owner: Any, lock: threading.Lock, answered: Callable[[], None] | None = None) -> Any:
    """A LifecycleNode class whose transitions call ``owner.on_<transition>() -> bool``."""
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.lifecycle import LifecycleNodeMixin, TransitionCallbackReturn
    from rclpy.node import Node

    def result(ok: bool) -> Any:
        return TransitionCallbackReturn.SUCCESS if ok else TransitionCallbackReturn.FAILURE

    class _Node(LifecycleNodeMixin, Node):  # type: ignore[misc]  # rclpy is untyped here
        def __init__(self, node_name: str, **kwargs: Any) -> None:
            Node.__init__(self, node_name, **kwargs)
            LifecycleNodeMixin.__init__(self, callback_group=ReentrantCallbackGroup())
            one_transition_at_a_time(self, lock, answered)

        def on_configure(self, state: Any) -> Any:
            return result(owner.on_configure())

        def on_activate(self, state: Any) -> Any:
            return result(owner.on_activate())

        def on_deactivate(self, state: Any) -> Any:
            return result(owner.on_deactivate())

        def on_cleanup(self, state: Any) -> Any:
            return result(owner.on_cleanup())

        def on_shutdown(self, state: Any) -> Any:
            return result(owner.on_shutdown())

        def on_error(self, state: Any) -> Any:
            return result(owner.on_cleanup())

    return _Node


class BorrowedNode:
    """Entities on a node owned by someone else (the lifecycle node): ``close()`` destroys what was
    created through it (publishers, subscriptions, services, parameters), never the node."""

    def __init__(self, owner: RclpyNode) -> None:
        self.owner, self.node = owner, owner.node
        self._destroy: list[Callable[[], Any]] = []

    @property
    def fully_qualified_name(self) -> str:
        return self.owner.fully_qualified_name

    def create_publisher(self, topic: str, type_name: str, qos: Any = None) -> Any:
        publisher = self.owner.create_publisher(topic, type_name, qos)
        self._destroy.append(lambda: self.node.destroy_publisher(publisher._publisher))
        return publisher

    def create_subscription(self, *args: Any, **kwargs: Any) -> Any:
        subscription = self.owner.create_subscription(*args, **kwargs)
        self._destroy.append(lambda: self.node.destroy_subscription(subscription))
        return subscription

    def create_service(self, *args: Any, **kwargs: Any) -> Any:
        service = self.owner.create_service(*args, **kwargs)
        self._destroy.append(lambda: self.node.destroy_service(service))
        return service

    def declare_fmu_parameters(self, parameters: list[Any], on_set: Any) -> None:
        callback = self.owner.declare_fmu_parameters(parameters, on_set)
        self._destroy.append(lambda: self.node.remove_on_set_parameters_callback(callback))
        names = [p.name for p in parameters]
        self._destroy.append(lambda: [self.node.undeclare_parameter(name) for name in names])

    def close(self) -> None:
        for destroy in reversed(self._destroy):
            try:
                destroy()
            except Exception:  # the node is going anyway: clean up what can be
                _log.debug("could not destroy a ROS entity", exc_info=True)
        self._destroy.clear()


class ManagedFmuNode:
    """The FMU node as a lifecycle node; ``build(ros_node)`` makes the (inactive) ``FmuNode``."""

    def __init__(
        self, build: Callable[[BorrowedNode], Any], name: str, namespace: str, domain_id: int | None
    ) -> None:
        self._build = build
        self.fmu: Any = None
        self.finished = threading.Event()  # finalized and the caller answered: the process may exit
        self._finalized = False
        self._lock = threading.Lock()
        self.ros = RclpyNode(
            name,
            namespace,
            domain_id=domain_id,
            node_class=lifecycle_class(self, threading.Lock(), self._answered),
            executor_threads=3,  # transitions, the other lifecycle services, the FMU's topics
        )

    def _say(self, text: str) -> None:
        self.ros.node.get_logger().info(text)

    def on_configure(self) -> bool:
        try:
            fmu = self._build(BorrowedNode(self.ros))
        except BridgeError as exc:
            self.ros.node.get_logger().error(f"configure failed: {exc}")
            return False
        with self._lock:
            self.fmu = fmu
        self._say(f"configured: {fmu.info.model_name} loaded, not stepping")
        return True

    def on_activate(self) -> bool:
        self.fmu.activate()
        self._say("active: stepping")
        return True

    def on_deactivate(self) -> bool:
        self.fmu.deactivate()
        self._say("inactive: not stepping")
        return True

    def on_cleanup(self) -> bool:
        with self._lock:
            fmu, self.fmu = self.fmu, None
        if fmu is not None:
            fmu.close()
        return True

    def on_shutdown(self) -> bool:
        self.on_cleanup()
        self._finalized = True  # the process ends once the caller has its answer (_answered)
        self._say("finalized: the process ends")
        return True

    def _answered(self) -> None:
        if self._finalized:
            self.finished.set()

    def close(self) -> None:
        self.on_cleanup()
        self.ros.close()
