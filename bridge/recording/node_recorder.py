"""``fmu-bridge record --node``: a running node's topics into an MCAP file, as ``ros2 bag record``.

The recorder subscribes to ``<prefix>/<node>/outputs`` and ``/actions``, decodes the frames
(``bridge.net.protocol``) and writes them as JointState messages named from the node's info reply
(``/outputs``: ``output_names``, ``/actions``: ``input_names``), on the recording clock of
:mod:`bridge.recording.meta`: an OUTPUTS frame at its simulation time, an ACTION frame for
step ``k`` at ``t_k-1`` (when it takes effect), each episode shifted to start after the last.
Episode numbers come from the frames; ERROR and REJECT frames become ``/events`` entries.
A node puts the OUTPUTS frame of its reset (step 0) on the wire too, so each episode of the
recording begins with its outputs at the start time.

A system's fixed-point iteration repeats a macro step on a node (``bridge.net.node_state``): the
same step then travels several times, each action after the first marked RESTORE_STATE, and only
the last pass is the step the system took. The recorder therefore holds back frames: the latest
OUTPUTS frame of each step and the latest ACTION frame of each step and client, of the newest
two steps of the current episode. A frame for a held (step, topic, client) replaces the held one
(``RecordStats.repeated``); a node's answer to a retried action is replaced the same way. Held
frames are written in the order they first arrived, so a recording without repeats is the one
writing every frame at once would give; they are written when a frame two steps later arrives
(one step of slack for frames of the two topics arriving out of order), before a frame of
another episode or an ERROR/REJECT frame, when more than 64 are held, and by ``close()``.

While it records, the recorder holds a liveliness token ``<prefix>/<node>/recorders/<id>`` and
answers a query on that key with its counts so far (:meth:`NodeRecorder.counts`, as JSON): how many
frames it has taken in per topic, so that a caller can tell when a run's last frame has arrived.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.errors import BridgeError, TransportError
from bridge.net import protocol as proto
from bridge.net.remote import query_info
from bridge.net.ros2 import cdr
from bridge.recording import meta
from bridge.recording.writer import McapWriter

_log = logging.getLogger(__name__)
TOPICS = ("outputs", "actions")
_MAX_STAMP_NS = (1 << 31) * 1_000_000_000  # builtin_interfaces/Time holds int32 seconds
_MAX_HELD = 64  # held frames beyond this (many clients acting on one step) are written at once
_Slot = tuple[str, int, int]  # topic, step, acting client (0 for outputs)


@dataclass
class _Episode:
    clock: meta.EpisodeClock
    last_step: int = 0


@dataclass
class _Held:
    """Frames of one episode not written yet, by slot in order of first arrival (a replaced
    frame keeps its slot's place), each with its header stamp."""

    episode: int
    newest: int = 0
    frames: dict[_Slot, tuple[int, proto.Frame]] = field(default_factory=dict)


@dataclass
class RecordStats:
    """Frames received per topic; malformed ones (not decodable, wrong size) and unplaced ones
    (well-formed, but their time or step lies outside what a recording can hold) were skipped;
    repeated ones (an earlier pass of a step a later frame replaced) were not written."""

    frames: dict[str, int] = field(default_factory=dict)
    malformed: int = 0
    unplaced: int = 0
    episodes: int = 0
    repeated: int = 0


class NodeRecorder:
    """Records one node's frames until ``stop()`` or ``close()``; a context manager."""

    def __init__(
        self,
        session: Any,
        node: str,
        path: str | Path,
        *,
        prefix: str = proto.DEFAULT_PREFIX,
        topics: tuple[str, ...] = TOPICS,
        timeout_s: float = 5.0,
        overwrite: bool = False,
    ) -> None:
        unknown = [t for t in topics if t not in TOPICS]
        if unknown or not topics:
            raise BridgeError(f"--topics {list(topics)}: choose from {list(TOPICS)} (comma-separated)")
        self.keys = proto.Keys(prefix, node)
        self.description = info = query_info(session, self.keys, timeout_s)
        self._start_ns = round(float(info["start_time_s"]) * 1e9)
        self._sampling_ns = round(float(info["sampling_time_s"]) * 1e9)
        names = {meta.OUTPUTS: list(info["output_names"]), meta.ACTIONS: list(info["input_names"])}
        names = {topic: n for topic, n in names.items() if topic.strip("/") in topics}
        self._layouts = {topic: cdr.JointStateLayout.of(n) for topic, n in names.items()}
        self.writer = McapWriter(path, overwrite=overwrite)
        self.channels = meta.open_channels(self.writer, [*names, meta.EVENTS], names)
        meta.write_run_metadata(self.writer, self._run_info())
        self.stats = RecordStats()
        self._episodes: dict[int, _Episode] = {}
        self._held: _Held | None = None
        self._clock = meta.RecordingClock(self._sampling_ns)
        self._frames: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._declared = [
            session.declare_subscriber(getattr(self.keys, t), self._callback(t)) for t in topics
        ]
        token = f"{self.keys.base}/recorders/{uuid.uuid4().hex[:8]}"
        self._declared.append(session.declare_queryable(token, self._on_counts, complete=True))
        self._declared.append(session.liveliness().declare_token(token))

    def counts(self) -> dict[str, Any]:
        """What the recorder has taken in so far: frames per topic, malformed, unplaced and
        repeated frames, episodes."""
        stats = self.stats
        return {
            "frames": dict(stats.frames),
            "malformed": stats.malformed,
            "unplaced": stats.unplaced,
            "repeated": stats.repeated,
            "episodes": stats.episodes,
        }

    def _on_counts(self, query: Any) -> None:
        query.reply(query.key_expr, meta.to_json(self.counts()))

    def _run_info(self) -> dict[str, Any]:
        info = self.description
        return {
            "env": "node recording",
            "node": self.keys.node,
            "prefix": self.keys.prefix,
            "fmu_sha256": info.get("fmu_sha256", ""),
            "step_size_s": info.get("step_size_s"),
            "sampling_time_s": info.get("sampling_time_s"),
            "start_time_s": info.get("start_time_s"),
            "node_mode": info.get("mode", ""),
            "experiment": info.get("experiment", ""),
            "version": info.get("version", ""),
            "node_info": info,
        }

    def _callback(self, topic: str) -> Any:
        put = self._frames.put

        def on_sample(sample: Any) -> None:
            put((topic, sample.payload.to_bytes()))

        return on_sample

    # -- recording -----------------------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> RecordStats:
        """Record until ``stop()`` is called or ``duration_s`` (wall clock) has passed."""
        deadline = time.monotonic() + duration_s if duration_s is not None else None
        while not self._stop.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                topic, payload = self._frames.get(timeout=0.1)
            except queue.Empty:
                continue
            self.handle(topic, payload)
        return self.stats

    def stop(self) -> None:
        """Make ``run()`` return (safe from signal handlers and other threads); ``close()``
        writes the frames still held."""
        self._stop.set()

    def handle(self, topic: str, payload: bytes) -> None:
        """Decode one frame and hold it (or write what it completes; see the module doc)."""
        try:
            frame = proto.decode(payload)
        except TransportError as exc:
            self.stats.malformed += 1
            _log.debug("dropped a malformed frame on %s: %s", topic, exc)
            return
        self.stats.frames[topic] = self.stats.frames.get(topic, 0) + 1
        if self._held is not None and self._held.episode != frame.episode:
            self._flush()
        episode = self._episode(frame.episode)
        if frame.kind in (proto.ERROR, proto.REJECT):
            self._flush()
            kind = "fmu_error" if frame.kind == proto.ERROR else "reject"
            event = {"event": kind, "episode": frame.episode, "step": frame.step, "message": frame.message}
            self._event(event, episode.clock.last_ns)
            return
        if frame.kind == proto.ACTION:
            stamp = self._start_ns + max(frame.step - 1, 0) * self._sampling_ns
            slot = (meta.ACTIONS, frame.step, frame.sim_time_ns)  # an action's last field: its client
        else:
            stamp, slot = frame.sim_time_ns, (meta.OUTPUTS, frame.step, 0)
        if self._recordable(slot[0], stamp, episode, frame):
            self._hold(slot, stamp, frame)

    def _recordable(self, topic: str, stamp_ns: int, episode: _Episode, frame: proto.Frame) -> bool:
        """Whether ``frame`` goes into the file (else it is counted as skipped, if it should be)."""
        layout = self._layouts.get(topic)
        if layout is None:
            return False
        if len(frame.floats) != len(layout.names):
            self.stats.malformed += 1
            return False
        # a header stamp holds int32 seconds; a log time is 0 .. 2^63-1 ns
        if abs(stamp_ns) >= _MAX_STAMP_NS or episode.clock.log_time(stamp_ns) is None:
            self.stats.unplaced += 1
            _log.debug("skipped a frame of episode %d at %d ns: it cannot be placed", frame.episode, stamp_ns)
            return False
        return True

    def _hold(self, slot: _Slot, stamp_ns: int, frame: proto.Frame) -> None:
        held = self._held
        if held is None:
            self._held = held = _Held(frame.episode)
        if slot in held.frames:
            self.stats.repeated += 1
        held.frames[slot] = (stamp_ns, frame)
        held.newest = max(held.newest, frame.step)
        self._flush(before_step=held.newest - 1 if len(held.frames) <= _MAX_HELD else None)

    def _flush(self, before_step: int | None = None) -> None:
        """Write the held frames in order of arrival: all, or those up to the first one whose
        step is ``before_step`` or later."""
        held = self._held
        if held is None:
            return
        episode = self._episodes[held.episode]
        while held.frames:
            slot = next(iter(held.frames))
            if before_step is not None and slot[1] >= before_step:
                return
            stamp_ns, frame = held.frames.pop(slot)
            self._write(slot[0], stamp_ns, episode, frame)
        self._held = None

    def _write(self, topic: str, stamp_ns: int, episode: _Episode, frame: proto.Frame) -> None:
        log = episode.clock.place(stamp_ns)
        if log is None:  # not after _recordable; counted all the same should that change
            self.stats.unplaced += 1
            return
        self.writer.add_message(
            self.channels[topic], log, self._layouts[topic].pack(stamp_ns, list(frame.floats))
        )
        if topic == meta.OUTPUTS:
            episode.last_step = max(episode.last_step, frame.step)

    def _episode(self, number: int) -> _Episode:
        found = self._episodes.get(number)
        if found is not None:
            return found
        if self._episodes:
            self._end_all()
        self._episodes[number] = found = _Episode(self._clock.begin(self._start_ns))
        self.stats.episodes += 1
        start = found.clock.last_ns
        self._event({"event": "episode_start", "episode": number, "time_s": self._start_ns / 1e9}, start)
        return found

    def _end_all(self) -> None:
        """End the open episode (a new one began, or the recording stops)."""
        number, episode = max(self._episodes.items(), key=lambda item: item[1].clock.last_ns)
        event = {"event": "episode_end", "episode": number, "steps": episode.last_step, "reason": None}
        self._event(event, episode.clock.last_ns)
        self._clock.end(max(e.clock.last_ns for e in self._episodes.values()))
        self.writer.flush()

    def _event(self, event: dict[str, Any], log: int) -> None:
        self.writer.add_message(self.channels[meta.EVENTS], log, cdr.encode_string(meta.to_json(event)))

    def close(self) -> Path:
        """Stop listening, write what arrived, finish the file; returns its path."""
        self.stop()
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        self._declared = []
        if self.writer.closed:
            return self.writer.path
        while True:
            try:
                self.handle(*self._frames.get_nowait())
            except queue.Empty:
                break
        self._flush()
        if self._episodes:
            self._end_all()
        return self.writer.close()

    def __enter__(self) -> NodeRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
