"""A state file over the wire: a client hands a node the FMU state its episodes start from.

Request on ``<prefix>/<node>/state`` (a query)::

    4 bytes   length L of the JSON part (little-endian, at most 1 KiB)
    L bytes   JSON {"client": id, "proof": hex} (``"clear": true`` to drop the state sent)
    N bytes   a state file (``bridge.fmu.state_file``), at most ``MAX_STATE_BYTES`` in all;
              none with ``clear``

Who may send one is who may reset: while a client holds the node, only that client, proving it
holds the session key with ``proof`` = MAC(key, ``state:<client>:<sha256 of the file>``), which
also binds the proof to these bytes; while nobody holds it, any client with a live token, or an
anonymous one (id 0). The file is checked (sizes, checksum) and must be a state of the node's FMU
(token, identifier, FMI version, interface) before the FMU deserialises it. From the next reset
on, every episode starts from it, until another state arrives, the state is cleared or the node
restarts. A clear request (proof = MAC(key, ``state:<client>:clear``)) goes back to the node's own
experiment: its state file if it names one, else initialisation. An isolated node hands the state
to its child process, which keeps it across the child's restarts.
The reply is JSON ``{"model", "time_s", "size"}`` (``{"cleared": true}``), or an error reply
``<code>: <why>``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import struct
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError
from bridge.fmu import state_file
from bridge.net import protocol as proto
from bridge.net.lease import Lease
from bridge.net.requests import BadRequest, Refused, redact

if TYPE_CHECKING:
    from bridge.net.node import FmuNode

_log = logging.getLogger(__name__)
_LENGTH = struct.Struct("<I")
MAX_AUTH_BYTES = 1024


def state_proof(key: bytes, client: int, data: bytes | None) -> str:
    """What the holder sends with a state file to show it holds ``key`` (bound to the file;
    ``data`` None: bound to clearing)."""
    what = "clear" if data is None else hashlib.sha256(data).hexdigest()
    return proto.mac(key, f"state:{client}:{what}".encode()).hex()


def encode_request(client: int, key: bytes | None, data: bytes) -> bytes:
    """A state request carrying the state file ``data``."""
    auth = {"client": client, "proof": state_proof(key, client, data) if key is not None else ""}
    text = json.dumps(auth).encode()
    return _LENGTH.pack(len(text)) + text + data


def encode_clear(client: int, key: bytes | None) -> bytes:
    """A request that drops the state sent to the node."""
    proof = state_proof(key, client, None) if key is not None else ""
    auth = {"client": client, "proof": proof, "clear": True}
    text = json.dumps(auth).encode()
    return _LENGTH.pack(len(text)) + text


def answer_state(node: FmuNode, query: Any) -> None:
    """Take a state file for the node's episodes, or reply with an error saying why not."""
    try:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        reply = take_state(node, payload)
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


def take_state(node: FmuNode, payload: bytes) -> dict[str, Any]:
    """Check a state request (size, sender, file, FMU) and make its state the episodes' start."""
    if len(payload) > proto.MAX_STATE_BYTES:
        raise BadRequest(
            f"state request: {len(payload)} bytes is more than the limit of {proto.MAX_STATE_BYTES} bytes"
        )
    client, proof, data = _parse(payload)
    _check_sender(node.lease, node.name, client, proof, data)
    start = getattr(node.plant, "start_from", None)
    if start is None:
        raise Refused("unsupported", f"node {node.name!r} serves a plant that cannot start from a state")
    if data is None:
        with node.locked("clearing its state"):
            node.saved.clear()
            start(None, "")
        node.counters["states_cleared"] += 1
        return {"cleared": True}
    source = f"the state sent to node {node.name!r}"
    saved = state_file.decode(data, source=source, max_bytes=len(data))
    with node.locked("taking a state file"):
        node.saved.clear()
        start(saved, source)
    node.counters["states_taken"] += 1
    header = saved.header
    return {"model": header.model_name, "time_s": header.time_s, "size": header.size}


def _parse(payload: bytes) -> tuple[int, str, bytes | None]:
    """The sender, its proof and the state file (None: a clear request)."""
    if len(payload) < _LENGTH.size:
        raise BadRequest("state request: no payload; send a length, the JSON part and a state file")
    (length,) = _LENGTH.unpack_from(payload)
    if length > MAX_AUTH_BYTES or _LENGTH.size + length > len(payload):
        raise BadRequest(f"state request: its JSON part claims {length} bytes (at most {MAX_AUTH_BYTES})")
    end = _LENGTH.size + length
    auth = proto.decode_json(payload[_LENGTH.size : end], "state request", limit=MAX_AUTH_BYTES)
    client, proof, clear = auth.get("client", 0), auth.get("proof", ""), auth.get("clear", False)
    if isinstance(client, bool) or not isinstance(client, int) or not 0 <= client <= proto.CLIENT_MAX:
        raise BadRequest(f"state request: 'client' must be an integer in [0, {proto.CLIENT_MAX}]")
    if not isinstance(proof, str) or len(proof) > 64 or set(auth) - {"client", "proof", "clear"}:
        raise BadRequest(
            "state request: expected {'client': id, 'proof': a hex string of <= 64 characters} "
            "and optionally 'clear': true"
        )
    if not isinstance(clear, bool):
        raise BadRequest(f"state request: 'clear' must be true or false, got {clear!r}")
    if clear:
        if len(payload) > end:
            extra = len(payload) - end
            raise BadRequest(f"state request: a clear request carries no state, got {extra} bytes")
        return client, proof, None
    return client, proof, payload[end:]


def _check_sender(lease: Lease, node: str, client: int, proof: str, data: bytes | None) -> None:
    holder = lease.holder
    if holder is None:
        if client and not lease.has_token(client):
            raise Refused("busy", f"node {node!r}: client {client:016x} has no liveliness token")
        return
    if holder.client != client or not client or proof != state_proof(holder.key, client, data):
        raise Refused("busy", lease.refusal(client) + "; only the holder's session may send it a state")


def _reply_err(node: FmuNode, query: Any, code: str, message: str) -> None:
    node.counters[f"state_{code}"] += 1
    query.reply_err(f"{code}: {redact(message)}".encode())
