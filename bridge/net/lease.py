"""Ownership of a node: one client at a time.

A client sends a random client id (``1 .. 2^63-1``) with every reset and in every ACTION frame,
and keeps a liveliness token ``<prefix>/<node>/clients/<id>`` while its session lives. The first
reset from a client grants it the lease; a reset from another client is refused with a message
naming the node and the holder unless it asks to ``take_over``; actions from anyone but the
holder are rejected. The lease ends when the holder's token disappears (its session closed or
its process died). A client id of 0 is anonymous: it may reset and act only while nobody holds
the node, and never holds it (tools, ``curl``-style probes, the ROS view).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Holder:
    client: int
    zid: str
    since: float  # wall clock, seconds since the epoch

    def describe(self) -> str:
        where = f" (Zenoh session {self.zid})" if self.zid else ""
        return f"client {self.client:016x}{where}"


class Lease:
    """Who holds a node; thread-safe (handlers run on Zenoh's threads)."""

    def __init__(self, node: str) -> None:
        self.node = node
        self.holder: Holder | None = None
        self.takeovers = 0
        self._lock = threading.Lock()

    def acquire(self, client: int, zid: str, take_over: bool) -> str | None:
        """Grant or keep the lease for a reset by ``client``; the refusal's reason otherwise."""
        with self._lock:
            holder = self.holder
            if holder is None or holder.client == client:
                if client and holder is None:
                    self.holder = Holder(client, zid, time.time())
                return None
            if take_over and client:
                self.holder = Holder(client, zid, time.time())
                self.takeovers += 1
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

    def allows(self, client: int) -> bool:
        """Whether an action from ``client`` may step the node (cheap: called every step)."""
        holder = self.holder
        return holder is None or holder.client == client

    def refusal(self, client: int) -> str:
        holder = self.holder
        who = holder.describe() if holder is not None else "nobody"
        return f"node {self.node!r} is held by {who}, not by client {client:016x}"

    def release_token(self, key: str) -> bool:
        """The liveliness token ``key`` of a client went away: end its lease if it held one."""
        with self._lock:
            holder = self.holder
            if holder is not None and key.endswith(f"/clients/{holder.client:016x}"):
                self.holder = None
                return True
            return False

    def describe(self) -> dict[str, Any] | None:
        holder = self.holder
        if holder is None:
            return None
        return {"client": f"{holder.client:016x}", "zid": holder.zid, "since": holder.since}
