"""``NodeClient``: one client's session with one node: stamped, signed actions out, the answer back.

The client has a random id and a liveliness token ``<prefix>/<node>/clients/<id>`` that backs its
lease and ends it when this session goes away; the reset reply gives it the session key its
actions are signed with and its answers are checked against (``bridge.net.lease``). How it waits
for an answer is a strategy (``bridge.net.channel``).
"""

from __future__ import annotations

import hmac
import json
import logging
import math
import queue
import secrets
import threading
import time
from collections.abc import Sequence
from typing import Any

from bridge.errors import BridgeError, PlantDied, StepError, StepTimeout, TransportError
from bridge.net import protocol as proto
from bridge.net.channel import EventWaiting, Waiting
from bridge.net.deadlines import SETTINGS, Deadlines, node_deadline_s
from bridge.net.discovery import every_reply, query_info, query_target, replier
from bridge.net.handshake import KeyPair, reply_proof, request_proof
from bridge.net.lease import NO_TOKEN
from bridge.net.transport import undeclare
from bridge.plant.base import MODEL_HUNG, Plant

_log = logging.getLogger(__name__)
_QUERY_LIFETIME_S = 7 * 86400.0  # a reset query's own timeout: the client ends it (Deadlines) first
_REPORT_S = 30.0  # how often a reset the node still works on is logged (INFO)
_DEAD = object()  # put in a waiting reset's queue when the node's liveliness token goes


class NodeClient:
    """Talks to one node: stamped actions out, the matching frame back.

    The client has a random id, sent with every reset and action, and a liveliness token
    ``<prefix>/<node>/clients/<id>`` that ends the node's lease when this session goes away.
    ``waiting`` says how it waits for an answer (``bridge.net.channel``; by default an Event).
    How long it waits follows the plant's measured speed (``bridge.net.deadlines``); ``timeout_s``
    is the shortest deadline.
    """

    def __init__(
        self,
        session: Any,
        node: str,
        *,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
        waiting: Waiting | None = None,
    ) -> None:
        self.keys = proto.Keys(prefix, node)
        self.name = node
        self.session = session
        self.timeout_s = timeout_s
        self.deadlines = Deadlines(timeout_s)
        self.take_over = take_over
        self.client_id = secrets.randbits(63) | 1
        self.notify: threading.Event | None = None  # set too whenever an answer arrives (vector envs)
        self.waiting: Waiting = waiting if waiting is not None else EventWaiting()
        self._resetting: queue.SimpleQueue[Any] = queue.SimpleQueue()  # the waiting reset's replies
        self.want: tuple[int, int] = (-1, -1)
        self.deadline = 0.0
        self.sent_at = 0.0  # when the last action went out (its answer's time is measured)
        self.frame: proto.Frame | None = None
        self.alive = True
        self.key: bytes | None = None  # the session key of the lease, agreed by the reset reply
        self.start_state = ""  # the SHA-256 of the sent state the node's episodes start from
        self._seq = 0  # this session's last request number (each is used once)
        # the token first: it reaches the node before any reset (a lease needs it), and its
        # declaration has gone through long before the info query's round trip is over
        token = session.liveliness().declare_token(self.keys.client(self.client_id))
        try:
            self.description = query_info(session, self.keys, timeout_s)
        except BaseException:
            undeclare(token)
            raise
        self.deadlines.node_s = node_deadline_s(self.description)
        self.node_zid = str(self.description.get("zid") or "")  # answers come from this session only
        self.outputs = len(self.description["output_names"])
        self._declared = [
            token,
            self.waiting.start(self),
            session.liveliness().declare_subscriber(self.keys.alive, self._on_liveliness, history=True),
        ]
        self._pub = session.declare_publisher(self.keys.actions)
        self._declared.append(self._pub)

    def take(self, frame: proto.Frame, payload: bytes) -> bool:
        """Keep ``frame`` if it answers the last action: its step, from the leased node's session
        (its MAC is right under the session key), and not another client's reject; whether it did."""
        if (frame.episode, frame.step) != self.want:
            return False
        if frame.kind == proto.REJECT and frame.sim_time_ns not in (0, self.client_id):
            return False
        key = self.key
        if key is not None and not proto.verify(payload, key):
            return False  # not from the node this client leased: another peer's frame
        self.frame = frame
        if frame.kind != proto.REJECT:
            self.deadlines.stepped(time.monotonic() - self.sent_at)
        return True

    def _on_liveliness(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE:
            self.alive = False
            self.waiting.wake()  # wake a waiting step at once
            self._resetting.put(_DEAD)  # and a waiting reset
        else:
            self.alive = True

    def send_action(
        self, plant: Plant, episode: int, step: int, inputs: Sequence[float], flags: int = 0
    ) -> None:
        """Publish the action for ``step``; ``flags``: SAVE_STATE or RESTORE_STATE (rollback)."""
        if not self.alive:
            raise self._dead(plant)
        self.frame = None
        self.waiting.arm()
        self.want = (episode, step)
        self.sent_at = now = time.monotonic()
        self.deadline = now + self.deadlines.step_s()
        action = proto.encode_values(
            proto.ACTION, episode, step, self.client_id, inputs, flags=flags, key=self.key
        )
        self._pub.put(action)
        self.waiting.sent()

    def ready(self) -> bool:
        """Whether ``wait`` would return (or raise) at once: an answer, a death or the deadline."""
        return self.waiting.ready()

    def wait(self, plant: Plant) -> proto.Frame:
        """The frame that answers the last action; raises if the node died or timed out."""
        if not self.waiting.wait():
            waited_s = time.monotonic() - self.sent_at
            raise plant.failure(
                StepTimeout,
                f"no answer within {waited_s:.3g} s",
                f"no outputs for step {self.want[1]} within {waited_s:.3g} s "
                f"({self.deadlines.explain('step')})",
                f"the node may be overloaded, stopped or unreachable; {SETTINGS} [{self.keys.base}]",
            )
        frame = self.frame
        if frame is None:
            raise self._dead(plant)
        return frame

    def _dead(self, plant: Plant, step: int | None = -1) -> PlantDied:
        fields: dict[str, Any] = {} if step == -1 else {"step": step}
        return plant.failure(
            PlantDied,
            "the plant died",
            "the node's liveliness token disappeared",
            f"restart it, or let RemoteVecEnv replace dead nodes [{self.keys.base}]",
            **fields,
        )

    def reset(self, plant: Plant, values: dict[str, Any], inputs: list[float]) -> proto.Frame:
        if not self.alive:
            raise self._dead(plant, step=None)
        episode = plant.episode
        pair = KeyPair()  # a grant agrees a new key with it; a held reset ignores it
        request: dict[str, Any] = {
            "episode": episode,
            "values": values,
            "inputs": inputs,
            "client": self.client_id,
            "zid": str(self.session.zid()),
            "take_over": self.take_over,
            "pub": pair.public.hex(),
        }
        if self.key is not None:  # the holder numbers its request; the attachment signs it
            request["seq"] = self._seq = self._seq + 1
        self.want = (episode, 0)
        payload = proto.encode_json(request)
        proof = request_proof(self.key, "reset", payload) if self.key is not None else None
        start = time.monotonic()
        while True:
            sent = time.monotonic()
            reply = self._ask_reset(plant, payload, proof)
            if reply is None:  # the query ended unanswered: nothing serves the reset key any more
                raise plant.failure(
                    PlantDied,
                    "the plant died",
                    "nothing answers on the node's reset key (the node stopped or died)",
                    f"restart it, or let RemoteVecEnv replace dead nodes [{self.keys.reset}]",
                    step=None,
                )
            if reply.ok is not None:
                frame = self._session(plant, reply.ok, episode, pair, payload)
                self.deadlines.reset_took(time.monotonic() - sent)
                return frame
            refusal = reply.err.payload.to_bytes().decode(errors="replace")
            if NO_TOKEN in refusal and time.monotonic() - start < 0.5 * self.timeout_s:
                time.sleep(0.05)  # the node has not seen this client's token yet: ask again
                continue
            raise self._reset_refused(plant, refusal)

    def _ask_reset(self, plant: Plant, payload: bytes, proof: bytes | None) -> Any:
        """The node's reply to one reset query (None: the query ended unanswered). A reset may
        initialise the FMU, which takes what the model needs: past the reset's deadline the
        client asks the node whether it still works (:meth:`_still_working`), and waits on while
        it does; a node that is gone, hung or silent ends the wait with an error."""
        import zenoh

        replies: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._resetting = replies
        token = zenoh.CancellationToken()
        self.session.get(
            self.keys.reset,
            zenoh.handlers.Callback(replies.put, lambda: replies.put(None)),
            payload=payload,
            attachment=proof,
            target=query_target(),
            consolidation=every_reply(),
            timeout=_QUERY_LIFETIME_S,
            cancellation_token=token,
        )
        sent = reported = time.monotonic()
        deadline = sent + self.deadlines.reset_s()
        try:
            while True:
                try:
                    reply = replies.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    call = self._still_working(plant, time.monotonic() - sent)
                    now = time.monotonic()
                    deadline = now + self.deadlines.floor_s  # asked again after another floor
                    if now - reported >= _REPORT_S:
                        reported = now
                        _log.info("node %s: %s, %.0f s so far", self.name, call, now - sent)
                    continue
                if reply is _DEAD:
                    raise self._dead(plant, step=None)
                if reply is None or not self.node_zid or replier(reply) in (None, self.node_zid):
                    return reply
                # another session answering for the node: not believed
        finally:
            token.cancel()

    def _still_working(self, plant: Plant, waited_s: float) -> str:
        """The call the node says it works on (its ``info``'s ``busy``), or the StepTimeout of a
        reset that outlasted its deadline: the node is hung, or answers no ``info`` either."""
        why = self.deadlines.explain("reset")
        hint = f"{SETTINGS} [{self.keys.reset}]"
        try:
            info = query_info(self.session, self.keys, self.deadlines.floor_s)
        except TransportError:
            raise plant.failure(
                StepTimeout,
                f"no answer within {waited_s:.3g} s",
                f"the reset request got no reply ({why}), and the node did not answer info within "
                f"{self.deadlines.floor_s:g} s",
                f"the node may be stopped, hung or unreachable; {hint}",
                step=None,
            ) from None
        if info.get("health") == "hung":
            raise plant.failure(StepTimeout, MODEL_HUNG, str(info.get("health_detail")), hint, step=None)
        busy = info.get("busy")
        if not isinstance(busy, dict):
            raise plant.failure(
                StepTimeout,
                f"no answer within {waited_s:.3g} s",
                f"the reset request got no reply ({why}), and the node works on no call: the request "
                "or its reply was lost",
                f"the node may be overloaded or unreachable; {hint}",
                step=None,
            )
        return f"still busy with {busy.get('call', 'a call')}"

    def send_state(self, data: bytes) -> dict[str, Any]:
        """Hand the node a state file (its bytes) to start its episodes from, from the next reset
        on, for as long as this client holds it (``bridge.net.node_start``); the node's JSON
        answer, or TransportError saying why not."""
        return self._state_request(data, "the state file")

    def clear_state(self) -> dict[str, Any]:
        """Drop the state sent to the node: its episodes start as its own experiment says again."""
        return self._state_request(None, "clearing its state")

    def _state_request(self, data: bytes | None, what: str) -> dict[str, Any]:
        from bridge.net.node_start import encode_request

        key, limit = self.keys.state, proto.MAX_REQUEST_BYTES
        if self.key is None:
            raise TransportError(
                f"node {self.name!r}: only the holder of a node may send it {what}; reset it first "
                f"(the reset starts this client's lease) [{key}]"
            )
        self._seq += 1
        payload = encode_request(self.client_id, self._seq, data)
        replies = self.session.get(
            key, payload=payload, attachment=request_proof(self.key, "state", payload),
            target=query_target(), consolidation=every_reply(), timeout=self.timeout_s,
        )  # fmt: skip
        for reply in replies:
            if self.node_zid and replier(reply) not in (None, self.node_zid):
                continue
            if reply.ok is not None:
                return proto.decode_json(reply.ok.payload.to_bytes(), "state reply", limit=limit)
            message = reply.err.payload.to_bytes().decode(errors="replace")
            raise TransportError(f"node {self.name!r} refused {what}: {message} [{key}]")
        raise TransportError(f"node {self.name!r} did not answer the state request [{key}]")

    def _session(self, plant: Plant, sample: Any, episode: int, pair: KeyPair, request: bytes) -> proto.Frame:
        """The step-0 frame of a reset reply and the session key, both checked: a new lease's
        key is agreed with the node's ``pub``; the reply proves it answers ``request`` itself."""
        payload = sample.payload.to_bytes()
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        try:
            words = proto.decode_json(attachment or b"null", "its attachment", limit=1024)
            pub, state, proof = (words.get(k) for k in ("pub", "state", "proof"))
            if not all(isinstance(w, str) for w in (pub, state, proof)):
                raise TransportError("its attachment lacks the strings pub, state and proof")
            key = self.key
            if pub:
                node_pub = bytes.fromhex(str(pub))
                key = pair.session_key(
                    node_pub, client_pub=pair.public, node_pub=node_pub, client=self.client_id
                )
            if key is None:
                raise TransportError("it starts no lease (no 'pub'), and this client holds none")
            if not hmac.compare_digest(bytes.fromhex(str(proof)), reply_proof(key, request, str(state))):
                raise TransportError("it does not prove it answers this request under the session key")
            if not proto.verify(payload, key):
                raise TransportError("its step-0 frame is not signed with the session key")
            frame = proto.decode(payload, expected_values=self.outputs)
            if (frame.kind, frame.episode, frame.step) != (proto.OUTPUTS, episode, 0):
                raise TransportError(
                    f"a {proto.KIND_NAMES[frame.kind]} frame for step {frame.step} of episode "
                    f"{frame.episode}, expected the outputs of step 0 of episode {episode}"
                )
        except (TransportError, ValueError) as exc:
            raise TransportError(f"{plant.name}: the reset reply is malformed: {exc}") from None
        if pub:
            self._seq = 0
        self.key, self.start_state = key, str(state)
        return frame

    def _reset_refused(self, plant: Plant, message: str) -> BridgeError:
        code, _, detail = message.partition(": ")
        if code == "unhealthy":
            return plant.failure(PlantDied, "the plant is unhealthy", detail, "restart the node", step=None)
        if code == "model_failed":  # the node's model failed at the reset: the error it raised there
            return _model_failed(plant, detail)
        return TransportError(f"{plant.name}: the reset was refused ({code}): {detail}")

    def close(self) -> None:
        self.waiting.close()
        for entity in reversed(self._declared):
            try:
                undeclare(entity)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        self._declared = []


def _model_failed(plant: Plant, text: str) -> BridgeError:
    """The StepError a node's plant raised at a reset (``bridge.net.node_replies.model_failure``),
    named after this plant; a reply that is not that JSON is a TransportError naming the node."""
    try:
        words = json.loads(text)
        what, detail, hint, log, time_s = (words[k] for k in ("what", "detail", "hint", "log", "time_s"))
        ok = all(isinstance(w, str) for w in (what, detail, hint)) and isinstance(log, list)
        ok = ok and (time_s is None or (isinstance(time_s, float | int) and math.isfinite(time_s)))
    except (ValueError, TypeError, KeyError):
        ok = False
    if not ok or not all(isinstance(line, str) for line in log) or not what:
        return TransportError(
            f"{plant.name}: the reset reply is malformed: a model_failed reply must be JSON with "
            f"the strings what, detail, hint, a list log and a time_s; got {text[:200]!r}"
        )
    return plant.failure(StepError, what, detail, hint, step=None, time_s=time_s, log=log[-20:])
