"""How a node client waits for its answer: a strategy object, chosen by who waits.

A :class:`~bridge.net.client.NodeClient` sends an action and then waits for the frame that
answers it; *how* it waits is one of two strategies with one interface (:class:`Waiting`):

- :class:`EventWaiting` (vector envs, the default): Zenoh hands each frame to a callback on its
  receive thread, which decodes it and sets an Event (and the client's ``notify`` Event, so that
  a vector env can wait for whichever node answers first).
- :class:`ChannelWaiting` (a system's master): Zenoh puts each frame in a ring channel without
  running Python, and the waiting thread, blocked in the channel's ``recv`` with the GIL
  released, takes it itself. Each answer then crosses threads once instead of twice, saved once
  per node and macro step (``benchmarks/bench_system.py``: about 30 us per node on loopback). A
  channel's ``recv`` has no timeout: a watchdog closes the channel when an answer is overdue
  (``bridge.net.deadlines``),
  and the end of the node's liveliness token closes it too; the next action opens a new one. A
  ring channel drops its oldest frame when full: a flood of frames never blocks Zenoh.

Which frame answers, and what it means, is the client's business (``NodeClient.take`` and
``bridge.net.remote.answer``): both strategies hand every frame to it.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any, Protocol

from bridge.errors import TransportError
from bridge.net import protocol as proto
from bridge.net.transport import undeclare
from bridge.net.watchdog import Watchdog

if TYPE_CHECKING:
    from bridge.net.client import NodeClient

CAPACITY = 64  # frames kept for the waiting thread; older ones are dropped


class Waiting(Protocol):
    """How a :class:`NodeClient` receives frames and waits for the one that answers."""

    def start(self, client: NodeClient) -> Any:
        """Subscribe to the client's node's frames; returns what ``close`` undeclares."""

    def arm(self) -> None:
        """Forget the last answer: an action is about to be sent."""

    def sent(self) -> None:
        """The action is out: its deadline runs."""

    def wait(self) -> bool:
        """Block until the answer arrives or the node dies (True), or the deadline (False)."""

    def ready(self) -> bool:
        """Whether ``wait`` would return at once."""

    def wake(self) -> None:
        """The node died: end a waiting ``wait`` now."""

    def close(self) -> None:
        """Stop any helper thread (the subscription is undeclared by the client)."""


class EventWaiting:
    """Frames through a callback on Zenoh's thread; an Event wakes the waiting thread."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._client: NodeClient | None = None

    def start(self, client: NodeClient) -> Any:
        self._client = client
        self._outputs = proto.PlainFrames(proto.OUTPUTS, client.outputs, signed=True)
        return client.session.declare_subscriber(client.keys.outputs, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        client = self._client
        payload = sample.payload.to_bytes()
        frame = read_frame(self._outputs, payload)
        if frame is not None and client is not None and client.take(frame, payload):
            self.wake()

    def wake(self) -> None:
        self._event.set()
        client = self._client
        if client is not None and client.notify is not None:
            client.notify.set()

    def arm(self) -> None:
        self._event.clear()

    def sent(self) -> None:
        pass

    def wait(self) -> bool:
        assert self._client is not None
        return self._event.wait(max(0.0, self._client.deadline - time.monotonic()))

    def ready(self) -> bool:
        assert self._client is not None
        return self._event.is_set() or time.monotonic() >= self._client.deadline

    def close(self) -> None:
        pass


class ChannelWaiting:
    """Frames through a Zenoh ring channel, read by the waiting thread itself."""

    def __init__(self) -> None:
        self._client: NodeClient | None = None
        self._overdue = False

    def start(self, client: NodeClient) -> Any:
        self._client = client
        self._outputs = proto.PlainFrames(proto.OUTPUTS, client.outputs, signed=True)
        self._channel = FrameChannel(client.session, client.keys.outputs)
        self._watchdog = Watchdog(client.timeout_s, self._on_overdue, name=f"client-{client.name}")
        return self._channel

    def _on_overdue(self, what: str, elapsed_s: float, deadline_s: float) -> None:
        self._overdue = True
        self._channel.close()

    def arm(self) -> None:
        if not self._channel.is_open:
            self._channel.open()
            self._overdue = False
            self._watchdog.rearm()

    def sent(self) -> None:
        assert self._client is not None
        self._watchdog.deadline_s = self._client.deadlines.step_s()  # it follows the measured speed
        self._watchdog.begin("step")

    def wait(self) -> bool:
        client = self._client
        assert client is not None
        try:
            while (payload := self._channel.recv()) is not None:
                frame = read_frame(self._outputs, payload)
                if frame is not None and client.take(frame, payload):
                    return True
        finally:
            self._watchdog.end()
        # Closed: by the end of the node's liveliness (dead: True) or by the watchdog (overdue).
        return not client.alive or not self._overdue

    def ready(self) -> bool:
        return not self._channel.is_open

    def wake(self) -> None:
        self._channel.close()

    def close(self) -> None:
        self._watchdog.stop()


def read_frame(outputs: proto.PlainFrames, payload: bytes) -> proto.Frame | None:
    """A frame from a node (None if malformed): a signed OUTPUTS frame of the node's size with one
    struct call, anything else decoded in full."""
    fields = outputs.read(payload)
    if fields is not None:
        return proto.Frame(proto.OUTPUTS, fields[3], fields[4], fields[5], fields[2], fields[7:-1])
    try:
        return proto.decode(payload)
    except TransportError:
        return None


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
