"""``ChannelClient``: a node client whose answers wait in a Zenoh channel for the stepping thread.

The callback path of :class:`bridge.net.remote.NodeClient` runs Python on Zenoh's receive
thread for every frame: it takes the GIL there, decodes, and wakes the waiting thread through an
Event, so each answer crosses threads twice and both fight for the GIL. Here Zenoh puts the
frame in a ring channel without Python, and the waiting thread, blocked in the channel's
``recv`` with the GIL released, takes it itself. A system master waits for every node of a
macro step, so this is saved once per node (``benchmarks/bench_system.py``: about 30 us per
node and macro step on loopback).

A channel's ``recv`` has no timeout. A watchdog closes the channel when an answer is overdue,
and the end of the node's liveliness token closes it too; ``recv`` then returns, and ``wait``
raises StepTimeout or PlantDied as the callback path does. The next action opens a new channel.
A ring channel drops its oldest frame when full: a flood of frames never blocks Zenoh.

Vector envs keep the callback path: they wait for whichever node answers first.
"""

from __future__ import annotations

import threading
from typing import Any

from bridge.errors import TransportError
from bridge.net import protocol as proto
from bridge.net.remote import NodeClient
from bridge.net.transport import undeclare
from bridge.net.watchdog import Watchdog
from bridge.plant.base import Plant

CAPACITY = 64  # frames kept for the waiting thread; older ones are dropped


class FrameChannel:
    """A node's outputs frames in a Zenoh ring channel; ``close`` (from any thread) ends a ``recv``."""

    def __init__(self, session: Any, key: str) -> None:
        self._session, self._key = session, key
        self._lock = threading.Lock()
        self._subscriber: Any = None
        self._handler: Any = None
        self.open()

    def open(self) -> None:
        import zenoh

        with self._lock:
            if self._subscriber is None:
                self._subscriber = self._session.declare_subscriber(
                    self._key, zenoh.handlers.RingChannel(CAPACITY)
                )
                self._handler = self._subscriber.handler

    @property
    def is_open(self) -> bool:
        return self._subscriber is not None

    def recv(self) -> bytes | None:
        """The next frame's payload; None once the channel is closed and empty."""
        import zenoh

        try:
            return self._handler.recv().payload.to_bytes()  # type: ignore[no-any-return]
        except zenoh.ZError:
            return None

    def close(self) -> None:
        with self._lock:
            subscriber, self._subscriber = self._subscriber, None
        if subscriber is not None:
            undeclare(subscriber)

    undeclare = close  # NodeClient.close undeclares what it declared


class ChannelClient(NodeClient):
    """A :class:`NodeClient` that receives its answers through a :class:`FrameChannel`."""

    def __init__(
        self, session: Any, node: str, *, prefix: str = proto.DEFAULT_PREFIX, timeout_s: float = 5.0
    ) -> None:
        self._overdue = False
        super().__init__(session, node, prefix=prefix, timeout_s=timeout_s)
        self._watchdog = Watchdog(timeout_s, self._on_overdue, name=f"client-{node}")

    def _subscribe_frames(self) -> FrameChannel:
        self._outputs = proto.PlainFrames(proto.OUTPUTS, len(self.description["output_names"]))
        self._channel = FrameChannel(self._session, self.keys.outputs)
        return self._channel

    def _on_overdue(self, what: str, elapsed_s: float) -> None:
        self._overdue = True
        self._channel.close()

    def _lost(self) -> None:
        self._channel.close()

    def _arm(self) -> None:
        self._frame = None
        if not self._channel.is_open:
            self._channel.open()
            self._overdue = False
            self._watchdog.rearm()

    def send_action(self, plant: Plant, episode: int, step: int, inputs: Any, flags: int = 0) -> None:
        super().send_action(plant, episode, step, inputs, flags)
        self._watchdog.begin("step")

    def _answered(self) -> bool:
        try:
            while (payload := self._channel.recv()) is not None:
                frame = self._read(payload)
                if frame is not None and self._answers(frame):
                    self._frame = frame
                    return True
        finally:
            self._watchdog.end()
        # Closed: by the end of the node's liveliness (an answer of None: dead) or by the watchdog.
        return not self.alive or not self._overdue

    def _read(self, payload: bytes) -> proto.Frame | None:
        """The frame (None if malformed): outputs with one struct call, the rest decoded."""
        fields = self._outputs.read(payload)
        if fields is not None:
            return proto.Frame(proto.OUTPUTS, fields[3], fields[4], fields[5], fields[2], fields[7:])
        try:
            return proto.decode(payload)
        except TransportError:
            return None

    def close(self) -> None:
        self._watchdog.stop()
        super().close()
