"""A node's Zenoh entities and its ROS view: declared together, torn down together.

``FmuNode`` hands its handlers over and gets back the outputs and clock publishers; this module
declares the action subscriber, the reset and info queryables, the client-token subscriber and
the node's liveliness tokens (``alive``, and ``unhealthy`` once the FMU hangs), and the optional
ROS view (``bridge.net.ros2.view``), whose requests it turns into the node's own calls.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError, TransportError
from bridge.net import node_start
from bridge.net import protocol as proto
from bridge.net.lease import Lease
from bridge.net.requests import redact
from bridge.net.ros2.params import fmu_parameters
from bridge.net.ros2.view import RosView, RosViewSettings
from bridge.net.transport import undeclare

if TYPE_CHECKING:
    from bridge.net.node import FmuNode

_log = logging.getLogger(__name__)
Handler = Callable[[Any], None]


class NodeLink:
    """The Zenoh entities of one node on ``session`` (closed with them when ``own_session``)."""

    def __init__(
        self,
        session: Any,
        keys: proto.Keys,
        *,
        own_session: bool,
        node: FmuNode,
        on_reset: Handler,
        on_info: Handler,
        on_state: Handler,
        lease: Lease,
    ) -> None:
        self.session, self.keys, self.own_session, self.lease = session, keys, own_session, lease
        self.node, self.counters = node, node.counters
        n = len(node.input_names)
        self._plain, self._signed = (
            proto.PlainFrames(proto.ACTION, n),
            proto.PlainFrames(proto.ACTION, n, signed=True),
        )
        self.zid = str(session.zid())
        _refuse_a_second_node(session, keys)
        self.outputs = session.declare_publisher(keys.outputs)
        self.clock = session.declare_publisher(keys.clock)
        self.ros: RosView | None = None
        self._unhealthy: Any = None
        self._declared: list[Any] = [self.outputs, self.clock]
        self._declared += [
            session.declare_subscriber(keys.actions, self._on_action),
            session.declare_queryable(keys.reset, on_reset, complete=True),
            session.declare_queryable(keys.info, on_info, complete=True),
            session.declare_queryable(keys.state, on_state, complete=True),
            session.liveliness().declare_subscriber(keys.client(0), self._on_client_token, history=True),
            session.liveliness().declare_token(keys.alive),
        ]

    def add_ros(self, node: FmuNode, settings: RosViewSettings, ros_node: Any = None) -> None:
        """The node's ROS view: actions and a reset Trigger by name (anonymous, never holding)."""
        self.ros = RosView(
            self.session,
            settings,
            name=node.name,
            output_names=node.output_names,
            input_names=node.input_names,
            on_actions=lambda values: ros_actions(node, values),
            on_reset=lambda: ros_reset(node, keep_inputs=settings.reset_keeps_inputs),
            realtime=node.mode == "realtime",
            follower=clock_follower(node, settings),
            parameters=fmu_parameters(node.info, node.served.settable, node.served.nominal),
            on_parameters=lambda changes: ros_parameters(node, changes),
            node=ros_node,
        )

    def _on_action(self, sample: Any) -> None:
        """An ACTION payload: a plain next step read with one struct call and stepped at once,
        anything else decoded in full and judged; malformed payloads counted and dropped."""
        node, payload = self.node, sample.payload.to_bytes()
        try:
            fields = self._signed.read(payload) or self._plain.read(payload)
            if fields is not None and not fields[2] & ~proto.SIGNED and node.plain_step(fields, payload):
                return
            try:
                frame = proto.decode_action(payload, len(node.input_names))
            except TransportError as exc:
                self._malformed(str(exc))
                return
            node.accept(frame, payload)
        except Exception:  # never let a handler die: count it, log it, keep serving
            self.counters["internal_errors"] += 1
            _log.exception("node %s: an action could not be handled", self.keys.node)

    def _malformed(self, reason: str) -> None:
        self.counters["malformed"] += 1
        n = self.counters["malformed"]
        if n <= 5 or n % 1000 == 0:
            _log.warning("node %s dropped a malformed payload (%d so far): %s", self.keys.node, n, reason)

    def _on_client_token(self, sample: Any) -> None:
        import zenoh

        try:
            client = int(str(sample.key_expr).rpartition("/")[2], 16)
        except ValueError:
            return  # not a client id: nothing a lease could be backed by
        if self.lease.token(client, alive=sample.kind != zenoh.SampleKind.DELETE):
            _log.info("node %s: the lease ended, its holder's session is gone", self.keys.node)
            if self.node.sent.sha256:  # its sent state ends with it, off Zenoh's callback thread
                ended = self.lease.leases
                threading.Thread(
                    target=node_start.end_with_lease, args=(self.node, ended), daemon=True
                ).start()

    def unhealthy(self) -> None:
        """Declare the ``unhealthy`` liveliness token (the FMU hung); it lives until the node ends."""
        if self._unhealthy is None:
            self._unhealthy = self.session.liveliness().declare_token(self.keys.unhealthy)

    def close_within(self, timeout_s: float) -> bool:
        """Undeclare everything (and close an own session) within ``timeout_s``; whether it was
        done in time (a callback stuck in a hung FMU keeps its entity busy)."""
        teardown = threading.Thread(target=self.close, name=f"close-{self.keys.node}", daemon=True)
        teardown.start()
        teardown.join(timeout=timeout_s)
        return not teardown.is_alive()

    def close(self) -> None:
        if self.ros is not None:
            self.ros.close()
        for entity in reversed([*self._declared, self._unhealthy]):
            if entity is None:
                continue
            try:
                undeclare(entity, attempts=20)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        if self.own_session:
            self.session.close()


def _refuse_a_second_node(session: Any, keys: proto.Keys) -> None:
    """A node of this name already serves: two would answer the same keys, so this one refuses."""
    for reply in session.liveliness().get(keys.alive, timeout=1.0):
        if reply.ok is not None:
            raise TransportError(
                f"a node named {keys.node!r} already serves on {keys.base}/*; stop it, or give this "
                "one another name (--name)"
            )


def ros_actions(node: FmuNode, values: dict[str, float]) -> None:
    """Input values by name from the ROS view: held in real time, one sample each in lockstep.
    A rejected action is counted by cause (``ros_rejected_<cause>``) and logged the first time."""
    if node.lockstep.inactive:  # the node's one rule for native clients, ROS and /clock alike
        return ros_rejected(node, "inactive", node.lockstep.inactive)
    if node.lease.holder is not None:
        return ros_rejected(node, "not_holder", "a client holds the node's lease (native protocol)")
    current = node.current_inputs()
    merged = [float(values.get(name, current[i])) for i, name in enumerate(node.input_names)]
    if not all(math.isfinite(v) for v in merged):
        return ros_rejected(node, "not_finite", f"an input is NaN or infinite: {values}")
    reason = node.rules.inputs(merged)
    if reason is not None:
        return ros_rejected(node, "out_of_range", reason)
    if not node.apply(merged):
        ros_rejected(node, "unhealthy", f"the node is unhealthy or busy: {node.health_detail}")
    return None


def ros_rejected(node: FmuNode, cause: str, reason: str) -> None:
    """Count a rejected ROS action; the first of each cause is logged with its reason, later ones
    only counted (a publisher of bad values at 1 kHz must not flood the log)."""
    key = f"ros_rejected_{cause}"
    node.counters[key] += 1
    if node.counters[key] == 1:
        _log.warning(
            "node %s: ROS action rejected (%s); further actions rejected for this reason are only "
            "counted (%s in fmu-bridge nodes --json)",
            node.name,
            reason,
            key,
        )


def ros_reset(node: FmuNode, *, keep_inputs: bool = False) -> tuple[bool, str]:
    """``~/reset``: back to t0 with the nominal values and, unless ``keep_inputs``
    (``ros.reset_keeps_inputs``), the inputs' start values: an action of the last episode is not
    held into the next."""
    refusal = node.lockstep.inactive or node.lease.acquire(0, "", False).refusal
    if refusal:
        return False, f"reset refused: {refusal}"
    inputs = None if keep_inputs else list(node.start_inputs)
    try:
        node.reset(dict(node.ros_parameters), inputs, node.lockstep.episode + 1)
    except BridgeError as exc:
        return False, redact(f"reset failed: {exc}")
    return True, f"reset to t0 (episode {node.lockstep.episode})"


def ros_parameters(node: FmuNode, changes: dict[str, Any]) -> str | None:
    """FMU parameters set over ROS: kept for the next ``~/reset`` between episodes; inside one,
    the reason they are refused."""
    state = node.lockstep
    if not node.episode_over():
        return (
            f"inside episode {state.episode} (step {state.step}) of node {node.name!r}: FMU parameters "
            "are set between episodes (before the first ~/reset, or once an episode has ended) and "
            "apply at the next ~/reset"
        )
    node.ros_parameters.update(changes)
    _log.info("node %s: FMU parameters %s apply at the next ~/reset", node.name, changes)
    return None


def clock_follower(node: FmuNode, settings: RosViewSettings) -> Any:
    """With ``ros.follow_clock``: the node steps on another simulator's /clock
    (:mod:`bridge.net.ros2.clock`); None otherwise."""
    if not settings.follow_clock:
        return None
    from bridge.net.ros2.clock import ClockFollower

    return ClockFollower(
        round(node.timing.sampling_time_s * 1e9), node.clock_start, node.clock_step, name=node.name
    )
