"""Ownership of a node: one client at a time, and a session only that client can speak for.

A client sends a random client id (``1 .. 2^63-1``) with every reset and in every ACTION frame,
and keeps a liveliness token ``<prefix>/<node>/clients/<id>`` while its session lives. A reset
from a client whose token the node has not seen is refused: a lease is always backed by a token,
and ends when the token ends (its session closed or its process died).

The first reset from a client grants it the lease and a **session key**: 32 random bytes that
travel only in the reset's reply (a Zenoh query reply goes to the querier alone). From then on
the holder's actions and the node's answers carry a MAC under that key (``proto.SIGNED``), so a
peer that copies the holder's client id (it is public: ``info`` shows it) cannot step the node,
and a peer that answers in the node's place is not believed. A later reset by the holder proves
itself with a MAC of its client id and episode (``reset_proof``); another client is refused
with a message naming the holder unless it asks to ``take_over``, which gives it a new key.
A client id of 0 is anonymous: it may reset and act only while nobody holds the node, and never
holds it (tools, ``curl``-style probes, the ROS view).
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from bridge.net import protocol as proto

NO_TOKEN = "has no liveliness token"


@dataclass(frozen=True)
class Holder:
    client: int
    zid: str
    since: float  # wall clock, seconds since the epoch
    key: bytes = field(repr=False, default=b"")

    def describe(self) -> str:
        where = f" (Zenoh session {self.zid})" if self.zid else ""
        return f"client {self.client:016x}{where}"


def reset_proof(key: bytes, client: int, episode: int) -> str:
    """What a holder sends with its next reset to show it holds ``key``."""
    return proto.mac(key, f"reset:{client}:{episode}".encode()).hex()


class Lease:
    """Who holds a node, and which clients have a live token; thread-safe (handlers run on
    Zenoh's threads)."""

    def __init__(self, node: str) -> None:
        self.node = node
        self.holder: Holder | None = None
        self.takeovers = 0
        self._live: set[int] = set()
        self._former: dict[int, bytes] = {}  # holders taken over: their keys, to tell them so
        self._lock = threading.Lock()

    @property
    def key(self) -> bytes | None:
        """The holder's session key (None while nobody holds the node)."""
        holder = self.holder
        return holder.key if holder is not None else None

    def acquire(
        self, client: int, zid: str, take_over: bool, *, episode: int = 0, proof: str = ""
    ) -> str | None:
        """Grant or keep the lease for a reset by ``client``; the refusal's reason otherwise."""
        with self._lock:
            if client and client not in self._live:
                return (
                    f"node {self.node!r}: client {client:016x} {NO_TOKEN}; a client declares "
                    "<prefix>/<node>/clients/<id> before its first reset (NodeClient does)"
                )
            holder = self.holder
            if holder is not None and holder.client == client and client and not take_over:
                if proof != reset_proof(holder.key, client, episode):
                    return (
                        f"node {self.node!r} is held by {holder.describe()}, and this reset does not "
                        "prove it comes from that session"
                    )
                return None
            if holder is None or (take_over and client):  # a take-over always starts a new session
                if client:
                    self.holder = Holder(client, zid, time.time(), secrets.token_bytes(proto.KEY_SIZE))
                    if holder is not None:
                        self.takeovers += 1
                        self._former = {**dict(list(self._former.items())[-7:]), holder.client: holder.key}
                return None
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
                return True
            return False

    def describe(self) -> dict[str, Any] | None:
        holder = self.holder
        if holder is None:
            return None
        return {"client": f"{holder.client:016x}", "zid": holder.zid, "since": holder.since}
