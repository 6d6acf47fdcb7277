"""Ownership of a node: one client at a time, and a session only that client can speak for.

A client sends a random client id (``1 .. 2^63-1``) with every reset and in every ACTION frame,
and keeps a liveliness token ``<prefix>/<node>/clients/<id>`` while its session lives. A reset
from a client whose token the node has not seen is refused: a lease is always backed by a token,
and ends when the token ends (its session closed or its process died).

A reset that grants a lease agrees a **session key** with the client (``bridge.net.handshake``:
X25519, the key is derived on both sides and never sent). From then on the holder's actions and
the node's answers carry a MAC under that key (``proto.SIGNED``), so a peer that copies the
holder's client id (it is public: ``info`` shows it) cannot step the node, and a peer that
answers in the node's place is not believed. Each later request of the holder (reset, state) is
signed as a whole and numbered; a number is accepted once and must grow (``seq``), so a
captured request replayed, verbatim or altered, into this lease or a later one, is refused. The
one exception makes a race harmless: the holder's last request arriving again while nothing
has happened since is answered as before, and does nothing (a participant that replays it
first leaves the holder's own request its answer). Another client is refused with a message
naming the holder unless it asks to ``take_over``, which starts a new lease with a new key.
A client id of 0 is anonymous: it may reset and act only while nobody holds the node, and never
holds it (tools, ``curl``-style probes, the ROS view). docs/protocol.md is the whole protocol.
"""

from __future__ import annotations

import hmac
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from bridge.errors import TransportError
from bridge.net import protocol as proto
from bridge.net.handshake import PUBLIC_SIZE, KeyPair, request_proof

NO_TOKEN = "has no liveliness token"
_USED_PUBS = 4096  # key-agreement keys of granted leases remembered, to refuse a replayed grant


@dataclass(frozen=True)
class Holder:
    client: int
    zid: str
    since: float  # wall clock, seconds since the epoch
    key: bytes = field(repr=False, default=b"")
    client_pub: bytes = field(repr=False, default=b"")
    node_pub: bytes = field(repr=False, default=b"")

    def describe(self) -> str:
        where = f" (Zenoh session {self.zid})" if self.zid else ""
        return f"client {self.client:016x}{where}"


@dataclass(frozen=True)
class Admission:
    """The lease's answer to a reset: ``refusal`` (None: go on); ``node_pub``, the node's half of
    the key agreement of a new lease (or of the grant answered again); ``repeat``: the holder's
    last request again, to answer as before without doing anything."""

    refusal: str | None = None
    node_pub: bytes = b""
    repeat: bool = False


class Lease:
    """Who holds a node, and which clients have a live token; thread-safe (handlers run on
    Zenoh's threads)."""

    def __init__(self, node: str) -> None:
        self.node = node
        self.holder: Holder | None = None
        self.takeovers = 0
        self.leases = 0  # leases granted so far: a sent state belongs to one of them
        self._live: set[int] = set()
        self._former: dict[int, bytes] = {}  # holders taken over: their keys, to tell them so
        self._seq = 0  # the holder's last accepted request number
        self._last = b""  # the holder's last accepted request (a reset), answered again if repeated
        self._used: deque[bytes] = deque(maxlen=_USED_PUBS)
        self._lock = threading.Lock()

    @property
    def key(self) -> bytes | None:
        """The holder's session key (None while nobody holds the node)."""
        holder = self.holder
        return holder.key if holder is not None else None

    def acquire(
        self,
        client: int,
        zid: str,
        take_over: bool,
        *,
        pub: bytes = b"",
        seq: int = 0,
        proof: bytes = b"",
        payload: bytes = b"",
    ) -> Admission:
        """Grant, keep or refuse the lease for a reset by ``client`` whose request is
        ``payload``: the holder's reset is signed (``proof``) and numbered (``seq``); a grant
        carries the client's key-agreement key ``pub``."""
        with self._lock:
            if client and client not in self._live:
                return Admission(
                    f"node {self.node!r}: client {client:016x} {NO_TOKEN}; a client declares "
                    "<prefix>/<node>/clients/<id> before its first reset (NodeClient does)"
                )
            holder = self.holder
            if holder is not None and holder.client == client and client:
                return self._held(holder, pub, seq, proof, payload)
            if holder is None or (take_over and client):  # a take-over always starts a new lease
                return self._grant(client, zid, pub, payload) if client else Admission()
            return Admission(self._busy(holder, client))

    def _held(self, holder: Holder, pub: bytes, seq: int, proof: bytes, payload: bytes) -> Admission:
        if not proof:
            if pub == holder.client_pub and payload == self._last and self._seq == 0:
                return Admission(node_pub=holder.node_pub, repeat=True)  # the grant, arriving again
            return Admission(
                f"node {self.node!r} is held by {holder.describe()}, and this reset does not prove it "
                "comes from that session (a request of the holder is signed with its session key)"
            )
        refusal = self._fresh(holder, seq, proof, payload, "reset")
        if refusal == "repeat":
            return Admission(repeat=True)
        if refusal is None:
            self._last = payload
        return Admission(refusal)

    def _grant(self, client: int, zid: str, pub: bytes, payload: bytes) -> Admission:
        if len(pub) != PUBLIC_SIZE:
            return Admission(
                f"node {self.node!r}: a reset that starts a lease carries the client's key-agreement "
                f"key 'pub' ({PUBLIC_SIZE} bytes as hex); got {len(pub)} bytes"
            )
        if pub in self._used:
            return Admission(f"node {self.node!r}: this reset replays one that started a lease before")
        pair = KeyPair()
        try:
            key = pair.session_key(pub, client_pub=pub, node_pub=pair.public, client=client)
        except TransportError as exc:
            return Admission(f"node {self.node!r}: {exc}")
        former = self.holder
        self.holder = Holder(client, zid, time.time(), key, pub, pair.public)
        self._used.append(pub)
        self._seq, self._last = 0, payload
        self.leases += 1
        if former is not None:
            self.takeovers += 1
            self._former = {**dict(list(self._former.items())[-7:]), former.client: former.key}
        return Admission(node_pub=pair.public)

    def _fresh(self, holder: Holder, seq: int, proof: bytes, payload: bytes, what: str) -> str | None:
        """None if ``payload`` is the holder's next request (signed, a new number); "repeat" if
        it is the last one again; else why it is refused. Called with the lock held."""
        if not hmac.compare_digest(proof, request_proof(holder.key, what, payload)):
            return (
                f"node {self.node!r} is held by {holder.describe()}, and this {what} request does not "
                "prove it comes from that session (its signature is wrong)"
            )
        if seq <= self._seq:
            if seq == self._seq and payload == self._last:
                return "repeat"
            return (
                f"node {self.node!r}: request number {seq} of this session was used already "
                f"(the last was {self._seq}): a replayed request"
            )
        self._seq = seq
        return None

    def admit_request(self, client: int, seq: int, proof: bytes, payload: bytes, what: str) -> str | None:
        """Whether a signed request other than a reset (``what``: ``state``) from ``client`` is
        the holder's next one; why not otherwise. Only the holder may send one."""
        with self._lock:
            holder = self.holder
            if holder is None or holder.client != client or not client:
                return self.refusal(client) + f"; only the holder's session may send a {what} request"
            return self._fresh(holder, seq, proof, payload, what)  # a state is never its last reset

    def _busy(self, holder: Holder, client: int) -> str:
        return (
            f"node {self.node!r} is held by {holder.describe()} since "
            f"{time.strftime('%H:%M:%S', time.localtime(holder.since))}; "
            + (
                "an anonymous client may not reset it: send a client id"
                if not client
                else "reset with take_over=True to take it over, or use another node"
            )
        )

    def has_token(self, client: int) -> bool:
        """Whether ``client``'s liveliness token is live."""
        return client in self._live

    def allows(self, client: int, payload: bytes) -> bool:
        """Whether an action ``payload`` from ``client`` may step the node: nobody holds it, or
        it comes from the holder's session (its MAC is right). Cheap: called every step."""
        holder = self.holder
        if holder is None:
            return True
        return holder.client == client and proto.verify(payload, holder.key)

    def former_key(self, client: int, payload: bytes) -> bytes | None:
        """The key of a holder that was taken over, if ``payload`` is signed with it: its
        ``not_holder`` reject is signed with that key, so it learns it lost the node (a peer that
        only copies its id is told nothing the former holder would believe)."""
        key = self._former.get(client)
        return key if key is not None and proto.verify(payload, key) else None

    def refusal(self, client: int) -> str:
        holder = self.holder
        who = holder.describe() if holder is not None else "nobody"
        return f"node {self.node!r} is held by {who}, not by a session of client {client:016x}"

    def token(self, client: int, alive: bool) -> bool:
        """A client's liveliness token appeared or went away; True when that ended the lease."""
        with self._lock:
            if alive:
                self._live.add(client)
                return False
            self._live.discard(client)
            holder = self.holder
            if holder is not None and holder.client == client:
                self.holder = None
                self._seq, self._last = 0, b""
                return True
            return False

    def describe(self) -> dict[str, Any] | None:
        holder = self.holder
        if holder is None:
            return None
        return {"client": f"{holder.client:016x}", "zid": holder.zid, "since": holder.since}
