"""The native wire protocol of an FMU node: key expressions and compact binary payloads.

Key expressions (``<prefix>`` defaults to ``fmu_bridge``, ``<node>`` is the node's name):

====================================  =========  ===============================================
key expression                        kind       payload
====================================  =========  ===============================================
``<prefix>/<node>/outputs``           put        ``Frame`` kind OUTPUTS, ERROR or REJECT
``<prefix>/<node>/actions``           put        ``Frame`` kind ACTION (FMU input values)
``<prefix>/<node>/reset``             query      request: JSON (``ResetRequest``); reply: OUTPUTS (step 0);
                                                 attachments: the holder's proof / the node's key half
``<prefix>/<node>/info``              query      no payload; reply: JSON (model, health, holder, counters)
``<prefix>/<node>/state``             query      request: a state file to start episodes from (``node_start``)
``<prefix>/<node>/clock``             put        int64 LE simulation time in ns (real-time mode)
``<prefix>/<node>/alive``             liveliness token while the node serves
``<prefix>/<node>/unhealthy``         liveliness token while the node's FMU is hung
``<prefix>/<node>/clients/<id>``      liveliness token of a client (16 hex digits) while it lives
====================================  =========  ===============================================

A frame is little-endian: a 24-byte header ``<BBHIqq`` (version, kind, flags, episode,
step, sim_time_ns) then either ``n`` float64 values (``<I`` count + ``n*8`` bytes) or, for
ERROR/REJECT, a UTF-8 message. One frame per sample: outputs of a step travel together with
the step index and simulation time, so consumers can lock step, detect loss and record. An
ACTION has no simulation time: its last header field carries the sender's client id (0:
anonymous), which the node checks against the holder of its lease; a REJECT carries the id of
the client whose action it refuses, so that no other client takes it for its own answer. An
ACTION's flags may ask the node
to save its FMU state before stepping (SAVE_STATE) or to go back to that saved state and step
again from there (RESTORE_STATE): a system's fixed-point iteration repeats a macro step this way
without a round trip of its own (``bridge.net.node_state``).

A frame flagged SIGNED ends in a 16-byte MAC (keyed BLAKE2b) of everything before it, under the
session key of the node's lease (``bridge.net.lease``): the holder signs its actions, the node
signs what it sends in the session, and each side believes only what verifies (:func:`verify`).
:func:`decode` reads a signed frame without its MAC (recorders and the deployed agent need no key).
The whole session protocol (threat model, the key agreement, signed and numbered requests) is
docs/protocol.md.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import struct
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import TransportError

VERSION = 1
OUTPUTS, ACTION, ERROR, REJECT = 1, 2, 3, 4
KIND_NAMES = {OUTPUTS: "outputs", ACTION: "action", ERROR: "error", REJECT: "reject"}

# flags
TERMINATED = 1  # the FMU requested termination at this step
FAILED = 2  # the step failed (ERROR frames): the episode is over
HUNG = 4  # (with FAILED) the FMU did not return within the node's step deadline
SAVE_STATE = 8  # (ACTION) save the FMU state, then step
RESTORE_STATE = 16  # (ACTION) back to the saved state (the step before this action), then step
SIGNED = 32  # the frame ends in a MAC of everything before it, keyed by the lease's session key
ACTION_FLAGS = SAVE_STATE | RESTORE_STATE | SIGNED
MAC_SIZE = 16  # keyed BLAKE2b, 128 bits
KEY_SIZE = 32  # a session key: agreed by the reset that grants a lease, never sent (handshake)

MAX_REQUEST_BYTES = 64 * 1024  # a reset request larger than this is refused unread
MAX_INFO_BYTES = 16 * 1024 * 1024  # an info reply larger than this is refused unread
MAX_STATE_BYTES = 16 * 1024 * 1024  # a state request larger than this is refused unread
MAX_SIGNALS = 100_000  # inputs or outputs a node may declare
MAX_JSON_DEPTH = 8  # reset requests are flat: deeper nesting is refused before parsing
EPISODE_MAX = 2**32 - 1  # the header's uint32
CLIENT_MAX = 2**63 - 1  # client ids travel in an int64 header field

HEADER = struct.Struct("<BBHIqq")
COUNT = struct.Struct("<I")
DEFAULT_PREFIX = "fmu_bridge"


@dataclass(frozen=True)
class Keys:
    """The key expressions of one node."""

    prefix: str
    node: str

    def __post_init__(self) -> None:
        for part, what in ((self.prefix, "prefix"), (self.node, "node name")):
            if not part or any(c in part for c in "*$?#") or part.startswith("/") or part.endswith("/"):
                raise TransportError(
                    f"{what} {part!r} is not usable in a key expression: use letters, digits, '_', '-', '/' "
                    "inside, and no wildcards"
                )

    @property
    def base(self) -> str:
        return f"{self.prefix}/{self.node}"

    @property
    def outputs(self) -> str:
        return f"{self.base}/outputs"

    @property
    def actions(self) -> str:
        return f"{self.base}/actions"

    @property
    def reset(self) -> str:
        return f"{self.base}/reset"

    @property
    def info(self) -> str:
        return f"{self.base}/info"

    @property
    def state(self) -> str:
        return f"{self.base}/state"

    @property
    def clock(self) -> str:
        return f"{self.base}/clock"

    @property
    def alive(self) -> str:
        return f"{self.base}/alive"

    @property
    def unhealthy(self) -> str:
        return f"{self.base}/unhealthy"

    def client(self, client_id: int) -> str:
        """The liveliness token of a client; ``client_id`` 0 gives the pattern of all of them."""
        return f"{self.base}/clients/{client_id:016x}" if client_id else f"{self.base}/clients/*"


@dataclass(slots=True)
class Frame:
    """One decoded message."""

    kind: int
    episode: int
    step: int
    sim_time_ns: int
    flags: int = 0
    floats: tuple[float, ...] = ()
    message: str = ""

    @property
    def values(self) -> npt.NDArray[np.float64]:
        """The carried values as a new float64 array (``floats`` as a tuple costs no numpy call:
        a node's hot path uses that)."""
        return np.array(self.floats, dtype=np.float64)

    @property
    def terminated(self) -> bool:
        return bool(self.flags & TERMINATED)


def encode_values(
    kind: int,
    episode: int,
    step: int,
    sim_time_ns: int,
    values: Any,
    *,
    flags: int = 0,
    key: bytes | None = None,
) -> bytes:
    """A frame carrying float64 values (OUTPUTS or ACTION): an array, or a sequence of numbers;
    with ``key``, flagged SIGNED and ending in its MAC."""
    if key is not None:
        flags |= SIGNED
    if isinstance(values, (list, tuple)):  # the hot path of nodes and clients: one struct call
        n = len(values)
        frame = _values_frame(n).pack(VERSION, kind, flags, episode, step, sim_time_ns, n, *values)
    else:
        array = np.ascontiguousarray(values, dtype="<f8")
        header = HEADER.pack(VERSION, kind, flags, episode, step, sim_time_ns)
        frame = header + COUNT.pack(array.size) + array.tobytes()
    return frame if key is None else frame + mac(key, frame)


def encode_message(
    kind: int,
    episode: int,
    step: int,
    sim_time_ns: int,
    message: str,
    *,
    flags: int = 0,
    key: bytes | None = None,
) -> bytes:
    """A frame carrying a text message (ERROR or REJECT); with ``key``, signed."""
    if key is not None:
        flags |= SIGNED
    frame = HEADER.pack(VERSION, kind, flags, episode, step, sim_time_ns) + message.encode("utf-8", "replace")
    return frame if key is None else frame + mac(key, frame)


def mac(key: bytes, data: bytes) -> bytes:
    """The MAC of ``data`` under a session ``key`` (keyed BLAKE2b, ``MAC_SIZE`` bytes)."""
    return hashlib.blake2b(data, key=key, digest_size=MAC_SIZE).digest()


def verify(payload: bytes, key: bytes) -> bool:
    """Whether ``payload`` is a frame flagged SIGNED whose MAC is right under ``key``: it was sent
    by the other end of the session (the node, or the client that holds it)."""
    if len(payload) < HEADER.size + MAC_SIZE or not payload[2] & SIGNED:
        return False
    return hmac.compare_digest(payload[-MAC_SIZE:], mac(key, payload[:-MAC_SIZE]))


def decode(payload: bytes, *, expected_values: int | None = None) -> Frame:
    """Decode a frame; a malformed or foreign payload raises TransportError saying why."""
    if len(payload) < HEADER.size:
        raise TransportError(f"payload of {len(payload)} bytes is shorter than the {HEADER.size}-byte header")
    version, kind, flags, episode, step, sim_time_ns = HEADER.unpack_from(payload)
    if flags & SIGNED:  # the MAC is the receiver's to check (``verify``): the frame is read without it
        if len(payload) < HEADER.size + MAC_SIZE:
            raise TransportError(f"a signed frame of {len(payload)} bytes has no room for its MAC")
        payload = payload[:-MAC_SIZE]
    if version != VERSION:
        raise TransportError(f"protocol version {version} is not supported (expected {VERSION})")
    if kind not in KIND_NAMES:
        raise TransportError(f"unknown frame kind {kind}")
    if kind in (ERROR, REJECT):
        text = payload[HEADER.size :].decode("utf-8", "replace")
        return Frame(kind, episode, step, sim_time_ns, flags, message=text)
    if len(payload) < HEADER.size + COUNT.size:
        raise TransportError("values frame without a value count")
    (count,) = COUNT.unpack_from(payload, HEADER.size)
    body = len(payload) - HEADER.size - COUNT.size
    if body != 8 * count:
        raise TransportError(f"values frame announces {count} values but carries {body} bytes")
    if expected_values is not None and count != expected_values:
        raise TransportError(f"expected {expected_values} values, got {count}")
    floats = _float64s(count).unpack_from(payload, HEADER.size + COUNT.size)
    return Frame(kind, episode, step, sim_time_ns, flags, floats=floats)


def decode_action(payload: bytes, inputs: int) -> Frame:
    """An ACTION frame of ``inputs`` values with a client id >= 0 and known flags, else
    TransportError saying what is wrong with it."""
    frame = decode(payload, expected_values=inputs)
    if frame.kind != ACTION:
        raise TransportError(f"a {KIND_NAMES[frame.kind]} frame on the actions key")
    if frame.sim_time_ns < 0:
        raise TransportError(f"client id {frame.sim_time_ns} is negative")
    if frame.flags & ~ACTION_FLAGS:
        raise TransportError(f"action flags {frame.flags:#x} are unknown")
    return frame


class PlainFrames:
    """Values frames of one kind and count, read with one ``struct`` call and no :class:`Frame`.

    The hot paths of a lockstep step (a node reading actions, a client reading outputs): exactly
    the frames :func:`decode` accepts with that kind and count. ``read`` returns None for any other
    payload, which is then :func:`decode`'s to refuse."""

    def __init__(self, kind: int, count: int, *, signed: bool = False) -> None:
        self._struct = _values_frame(count, signed)
        self._kind, self._count, self._signed = kind, count, SIGNED if signed else 0

    def read(self, payload: bytes) -> tuple[Any, ...] | None:
        """``(version, kind, flags, episode, step, stamp, count, *values[, mac])``, the stamp
        being the simulation time (outputs) or the client id (actions), the MAC last when signed
        (unchecked: see ``verify``); None if not such a frame."""
        if len(payload) != self._struct.size:
            return None
        fields = self._struct.unpack(payload)
        if fields[0] != VERSION or fields[1] != self._kind or fields[6] != self._count:
            return None
        if fields[2] & SIGNED != self._signed:
            return None
        return fields


@lru_cache(maxsize=64)
def _float64s(count: int) -> struct.Struct:
    return struct.Struct(f"<{count}d")


@lru_cache(maxsize=128)
def _values_frame(count: int, signed: bool = False) -> struct.Struct:
    """A whole values frame of ``count`` values: header, count, values (and a MAC when signed)."""
    return struct.Struct(f"<BBHIqqI{count}d" + (f"{MAC_SIZE}s" if signed else ""))


def encode_json(data: dict[str, Any]) -> bytes:
    return json.dumps(data, separators=(",", ":"), default=_jsonable).encode()


def decode_json(payload: bytes, what: str, *, limit: int | None = None) -> dict[str, Any]:
    """A JSON object; with ``limit``, a payload longer than ``limit`` bytes or nested deeper than
    ``MAX_JSON_DEPTH`` is refused before it is parsed (no memory or recursion blow-up)."""
    if limit is not None:
        if len(payload) > limit:
            raise TransportError(f"{what}: {len(payload)} bytes is more than the limit of {limit} bytes")
        if _depth(payload) > MAX_JSON_DEPTH:
            raise TransportError(f"{what}: JSON nested deeper than {MAX_JSON_DEPTH} levels")
    try:
        data = json.loads(payload.decode())
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError, ValueError) as exc:
        raise TransportError(f"{what}: not JSON ({str(exc)[:200]})") from None
    if not isinstance(data, dict):
        raise TransportError(f"{what}: expected a JSON object, got {type(data).__name__}")
    return data


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _depth(payload: bytes) -> int:
    """Bracket nesting depth, counting brackets outside strings only (an upper bound is enough)."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in payload:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest
