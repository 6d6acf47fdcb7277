"""Reading recordings back: ``read_recording`` (finished or ``.part``) and ``recover``.

Both read the file front to back with the ``mcap`` package's stream reader, which expands
chunks as it goes. A file whose writer was killed ends inside its last chunk: everything
before it is read, and the rest is reported as lost (``Recording.complete`` is False).
``recover`` rewrites that readable part as a valid, indexed ``.mcap`` that every reader
(rosbags, ``ros2 bag``, Foxglove, Rerun) opens.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError
from bridge.recording import cdr
from bridge.recording.writer import PART_SUFFIX, McapWriter

_log = logging.getLogger(__name__)
IntArray = npt.NDArray[np.int64]


@dataclass
class Series:
    """The messages of one channel, decoded into arrays.

    ``values`` is ``(n, len(names))`` for JointState channels and ``(n,)`` for Float64 ones;
    ``texts`` holds String messages. ``stamp_ns`` is the header stamp (or the log time for
    types without a header).
    """

    topic: str
    msgtype: str
    names: list[str]
    log_ns: IntArray
    stamp_ns: IntArray
    values: npt.NDArray[np.float64]
    texts: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.log_ns)

    @property
    def stamped(self) -> bool:
        """Whether the type has a header stamp (else ``stamp_ns`` repeats the log time)."""
        return self.msgtype == cdr.JOINT_STATE


@dataclass(frozen=True)
class Episode:
    index: int
    start_ns: int
    end_ns: int | None
    scenario: str | None
    seed: int | None
    steps: int | None
    episode_return: float | None
    reason: str | None
    drawn: dict[str, float]


@dataclass(frozen=True)
class Attachment:
    name: str
    media_type: str
    data: bytes


@dataclass
class Recording:
    """A recording read into memory."""

    path: Path
    complete: bool
    profile: str
    library: str
    series: dict[str, Series]
    metadata: dict[str, dict[str, str]]
    attachments: list[Attachment]
    message_counts: dict[str, int]

    @cached_property
    def events(self) -> list[dict[str, Any]]:
        """The decoded JSON events (episode start/end, errors), in log-time order."""
        series = self.series.get("/events")
        if series is None:
            return []
        events = []
        for log_ns, text in zip(series.log_ns, series.texts):
            try:
                events.append(dict(json.loads(text), log_ns=int(log_ns)))
            except (json.JSONDecodeError, TypeError, ValueError):
                _log.info("skipped an event that is not a JSON object: %.80s", text)
        return events

    @cached_property
    def episodes(self) -> list[Episode]:
        """The episodes marked by start/end events, in order (an unfinished one has no end)."""
        return _episodes(self.events)


def _episodes(events: list[dict[str, Any]]) -> list[Episode]:
    found: list[Episode] = []
    start: dict[str, Any] | None = None
    for event in [*events, {"event": "episode_start"}]:  # the sentinel closes the last
        kind = event.get("event")
        if kind not in ("episode_start", "episode_end"):
            continue
        if start is not None:
            end = event if kind == "episode_end" else {}
            found.append(
                Episode(
                    index=int(start.get("episode", len(found))),
                    start_ns=int(start["log_ns"]),
                    end_ns=end.get("log_ns"),
                    scenario=start.get("scenario"),
                    seed=start.get("seed"),
                    steps=end.get("steps"),
                    episode_return=end.get("return"),
                    reason=end.get("reason"),
                    drawn=dict(start.get("drawn") or {}),
                )
            )
        start = event if kind == "episode_start" and "log_ns" in event else None
    return found


@dataclass
class _Raw:
    topic: str
    msgtype: str
    log_ns: list[int] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)


def _records(path: Path) -> Iterator[Any]:
    """MCAP records of ``path`` in file order; stops quietly at a truncated end."""
    from mcap.exceptions import McapError
    from mcap.stream_reader import StreamReader

    with path.open("rb") as stream:
        try:
            yield from StreamReader(stream).records
        except (McapError, EOFError, ValueError) as exc:
            _log.warning("%s ends early (%s): read up to its last complete chunk", path, type(exc).__name__)


def read_recording(path: str | Path) -> Recording:
    """Read a recording (``.mcap``, or an unfinished ``.mcap.part`` up to its last chunk)."""
    path = Path(path)
    if not path.is_file():
        unfinished = path.with_name(path.name + PART_SUFFIX)
        hint = f"; an unfinished recording exists: {unfinished}" if unfinished.is_file() else ""
        raise BridgeError(f"no recording at {path}{hint}")
    from mcap.records import Attachment as McapAttachment
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema

    schemas: dict[int, str] = {}
    raw: dict[int, _Raw] = {}
    metadata: dict[str, dict[str, str]] = {}
    attachments: list[Attachment] = []
    header, complete = None, False
    for record in _records(path):
        if isinstance(record, Message):
            if record.channel_id in raw:
                raw[record.channel_id].log_ns.append(record.log_time)
                raw[record.channel_id].data.append(record.data)
        elif isinstance(record, Schema):
            schemas.setdefault(record.id, record.name)
        elif isinstance(record, Channel) and record.id not in raw:
            raw[record.id] = _Raw(record.topic, schemas.get(record.schema_id, ""))
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
        elif isinstance(record, McapAttachment):
            attachments.append(Attachment(record.name, record.media_type, bytes(record.data)))
        elif isinstance(record, Header):
            header = record
        elif isinstance(record, Footer):
            complete = True
    if header is None:
        raise BridgeError(f"{path} is not an MCAP file (no MCAP header)")
    series = {r.topic: _decode(r) for r in raw.values()}
    counts = {r.topic: len(r.data) for r in raw.values()}
    return Recording(path, complete, header.profile, header.library, series, metadata, attachments, counts)


def _decode(raw: _Raw) -> Series:
    log_ns = np.array(raw.log_ns, dtype=np.int64)
    if raw.msgtype == cdr.JOINT_STATE:
        names, stamps, values = cdr.decode_joint_states(raw.data)
        return Series(raw.topic, raw.msgtype, names, log_ns, stamps, values)
    if raw.msgtype == cdr.FLOAT64:
        values = np.array([cdr.decode_float64(d) for d in raw.data], dtype=np.float64)
        return Series(raw.topic, raw.msgtype, [raw.topic.strip("/")], log_ns, log_ns, values)
    if raw.msgtype == cdr.STRING:
        texts = [cdr.decode_string(d) for d in raw.data]
        return Series(raw.topic, raw.msgtype, [], log_ns, log_ns, np.zeros(0), texts)
    _log.info("channel %s has type %s, which fmu-bridge does not decode", raw.topic, raw.msgtype)
    return Series(raw.topic, raw.msgtype, [], log_ns, log_ns, np.zeros(0))


def recovered_name(part: Path) -> Path:
    return part.with_name(part.name.removesuffix(PART_SUFFIX)) if part.name.endswith(PART_SUFFIX) else part


def recover(part: str | Path, output: str | Path | None = None, *, overwrite: bool = False) -> Path:
    """Rewrite everything readable in an unfinished recording into a valid ``.mcap``.

    Args:
        part: the unfinished file (``NAME.mcap.part``).
        output: where to write (default: ``NAME.mcap`` beside it).
        overwrite: replace ``output`` if it exists.

    Returns the path written. Messages keep their channel, log and publish times and sequence.
    """
    from mcap.records import Attachment as McapAttachment
    from mcap.records import Channel, Header, Message, Metadata, Schema

    source = Path(part)
    target = Path(output) if output is not None else recovered_name(source)
    if not source.is_file():
        raise BridgeError(f"no file to recover at {source}")
    if target.resolve() == source.resolve():
        raise BridgeError(f"recover {source}: give an output name other than the input (e.g. NAME.mcap)")
    if target.exists() and not overwrite:
        raise BridgeError(f"{target} exists; pass --force to overwrite it")
    records = _records(source)
    first = next(records, None)
    if not isinstance(first, Header):
        raise BridgeError(f"{source} does not start with an MCAP header: nothing to recover")
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    work = target.with_name(target.name + ".recovering" + PART_SUFFIX)  # never the source itself
    with McapWriter(
        target, profile=first.profile, library=first.library, work_path=work, overwrite=True
    ) as writer:
        for record in records:
            if isinstance(record, Message) and record.channel_id in channels:
                writer.add_message(
                    channels[record.channel_id],
                    record.log_time,
                    record.data,
                    publish_time=record.publish_time,
                    sequence=record.sequence,
                )
            elif isinstance(record, Schema) and record.id not in schemas:
                schemas[record.id] = writer.add_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel) and record.id not in channels:
                schema_id = schemas.get(record.schema_id, 0)
                channels[record.id] = writer.add_channel(
                    record.topic, schema_id, record.message_encoding, record.metadata
                )
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, record.metadata)
            elif isinstance(record, McapAttachment):
                writer.add_attachment(
                    record.name,
                    record.media_type,
                    bytes(record.data),
                    log_time=record.log_time,
                    create_time=record.create_time,
                )
    _log.info("recovered %d messages from %s into %s", writer.message_count, source, target)
    return target
