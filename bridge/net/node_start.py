"""A state file over the wire: the holder hands a node the FMU state its episodes start from.

Request on ``<prefix>/<node>/state`` (a query)::

    4 bytes   length L of the JSON part (little-endian, at most 1 KiB)
    L bytes   JSON {"client": id, "seq": n} (``"clear": true`` to drop the state sent)
    N bytes   a state file (``bridge.fmu.state_file``), at most ``MAX_STATE_BYTES`` in all;
              none with ``clear``

with the query's attachment the holder's signature of the whole payload
(``handshake.request_proof(key, "state", payload)``), ``seq`` its next request number (shared
with its resets: each number is accepted once). A state is executable input to the FMU, which
deserialises its bytes (docs/protocol.md), so:

- only the holder of the node's lease may send one (nobody, while nobody holds it; never an
  anonymous client);
- a node loads a sent state only in an isolated child process (``--isolate`` or
  ``model.isolation``): a crafted state that crashes the FMU kills that child, never the node,
  and the next reset starts a fresh child;
- a sent state ends with the lease it was sent in: when the holder's session ends or another
  client takes the node over, episodes start as the node's experiment says again;
- ``info`` (``start_state``) and every reset reply (``state``) name the active sent state by the
  SHA-256 of its bytes ("" for none).

The file is checked (sizes, checksum) and must be a state of the node's FMU (token, identifier,
FMI version, interface) before the child deserialises it. The reply is JSON
``{"model", "time_s", "size", "sha256"}`` (``{"cleared": true}``), or an error reply
``<code>: <why>``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError
from bridge.fmu import state_file
from bridge.net import protocol as proto
from bridge.net.requests import BadRequest, Refused, redact

if TYPE_CHECKING:
    from bridge.net.node import FmuNode

_log = logging.getLogger(__name__)
_LENGTH = struct.Struct("<I")
MAX_AUTH_BYTES = 1024


@dataclass(frozen=True)
class SentState:
    """The state the node's holder sent: the SHA-256 of its bytes, and the lease it ends with."""

    sha256: str = ""
    lease: int = 0


def encode_request(client: int, seq: int, data: bytes | None) -> bytes:
    """A state request carrying the state file ``data`` (None: a request to clear it)."""
    auth: dict[str, Any] = {"client": client, "seq": seq}
    if data is None:
        auth["clear"] = True
    text = json.dumps(auth).encode()
    return _LENGTH.pack(len(text)) + text + (data or b"")


def active_state(node: FmuNode) -> str:
    """The SHA-256 of the sent state the node's episodes start from ("" for none)."""
    return node.sent.sha256


def end_with_lease(node: FmuNode, ended: int | None = None) -> None:
    """The lease a state was sent in has ended (``ended``, its number; None: every lease before
    the current one): episodes start as the experiment says again."""
    sent = node.sent
    if not sent.sha256 or (ended is not None and sent.lease != ended):
        return
    start = getattr(node.plant, "start_from", None)
    try:
        with node.locked("dropping the state of an ended lease"):
            node.saved.clear()
            if start is not None:
                start(None, "")
            node.sent = SentState()
    except BridgeError as exc:  # a dead child forgets it anyway: a restarted one gets no state
        _log.warning("node %s: the state of an ended lease could not be dropped: %s", node.name, exc)
        node.sent = SentState()
    node.counters["states_ended_with_lease"] += 1


def answer_state(node: FmuNode, query: Any) -> None:
    """Take a state file for the node's episodes, or reply with an error saying why not."""
    try:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        attachment = query.attachment
        proof = attachment.to_bytes() if attachment is not None else b""
        reply = take_state(node, payload, proof[:64])
    except BadRequest as exc:
        return _reply_err(node, query, "bad_request", str(exc))
    except Refused as exc:
        return _reply_err(node, query, exc.code, str(exc))
    except BridgeError as exc:
        return _reply_err(node, query, "refused", f"the state was refused: {exc}")
    except Exception as exc:  # never let a handler die
        _log.exception("node %s: a state request could not be handled", node.name)
        why = f"the node could not take the state ({type(exc).__name__})"
        return _reply_err(node, query, "internal", why)
    query.reply(node.keys.state, proto.encode_json(reply))
    return None


def take_state(node: FmuNode, payload: bytes, proof: bytes = b"") -> dict[str, Any]:
    """Check a state request (size, sender, file, FMU) and make its state the episodes' start."""
    if len(payload) > proto.MAX_STATE_BYTES:
        raise BadRequest(
            f"state request: {len(payload)} bytes is more than the limit of {proto.MAX_STATE_BYTES} bytes"
        )
    client, seq, data = _parse(payload)
    refusal = node.lease.admit_request(client, seq, proof, payload, "state")
    if refusal is not None:
        raise Refused("busy", refusal)
    start = getattr(node.plant, "start_from", None)
    if start is None:
        raise Refused("unsupported", f"node {node.name!r} serves a plant that cannot start from a state")
    if data is None:
        with node.locked("clearing its state"):
            node.saved.clear()
            start(None, "")
            node.sent = SentState()
        node.counters["states_cleared"] += 1
        return {"cleared": True}
    if not node.isolated:
        raise Refused(
            "unsupported",
            f"node {node.name!r} runs its FMU in its own process, and a sent state is loaded only in an "
            "isolated child (the FMU deserialises its bytes): serve the node with --isolate or "
            "model.isolation",
        )
    source = f"the state sent to node {node.name!r}"
    saved = state_file.decode(data, source=source, max_bytes=len(data))
    sha = hashlib.sha256(data).hexdigest()
    with node.locked("taking a state file"):
        node.saved.clear()
        start(saved, source)
        node.sent = SentState(sha, node.lease.leases)
    node.counters["states_taken"] += 1
    header = saved.header
    return {"model": header.model_name, "time_s": header.time_s, "size": header.size, "sha256": sha}


def _parse(payload: bytes) -> tuple[int, int, bytes | None]:
    """The sender, its request number and the state file (None: a clear request)."""
    if len(payload) < _LENGTH.size:
        raise BadRequest("state request: no payload; send a length, the JSON part and a state file")
    (length,) = _LENGTH.unpack_from(payload)
    if length > MAX_AUTH_BYTES or _LENGTH.size + length > len(payload):
        raise BadRequest(f"state request: its JSON part claims {length} bytes (at most {MAX_AUTH_BYTES})")
    end = _LENGTH.size + length
    auth = proto.decode_json(payload[_LENGTH.size : end], "state request", limit=MAX_AUTH_BYTES)
    client, seq, clear = auth.get("client", 0), auth.get("seq", 0), auth.get("clear", False)
    for name, value in (("client", client), ("seq", seq)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= proto.CLIENT_MAX:
            raise BadRequest(f"state request: {name!r} must be an integer in [0, {proto.CLIENT_MAX}]")
    if set(auth) - {"client", "seq", "clear"}:
        raise BadRequest(
            "state request: expected {'client': id, 'seq': request number} and optionally 'clear': true"
        )
    if not isinstance(clear, bool):
        raise BadRequest(f"state request: 'clear' must be true or false, got {clear!r}")
    if clear:
        if len(payload) > end:
            extra = len(payload) - end
            raise BadRequest(f"state request: a clear request carries no state, got {extra} bytes")
        return client, seq, None
    return client, seq, payload[end:]


def _reply_err(node: FmuNode, query: Any, code: str, message: str) -> None:
    node.counters[f"state_{code}"] += 1
    query.reply_err(f"{code}: {redact(message)}".encode())
