"""Reading recordings back: ``read_recording`` (finished or ``.part``) and ``recover``.

Both read the file front to back with :mod:`bridge.recording.scan`, a bounded reader that
expands chunks as it goes. A file whose writer was killed ends inside its last chunk:
everything before it is read, and the rest is reported as lost (``Recording.complete`` is
False, ``Recording.problems`` says what was skipped). ``recover`` rewrites that readable part
as a valid, indexed ``.mcap`` that every reader (rosbags, ``ros2 bag``, Foxglove, Rerun) opens.
"""

from __future__ import annotations

import json
import logging
import os
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError
from bridge.net.ros2 import cdr
from bridge.recording import scan
from bridge.recording.writer import PART_SUFFIX, McapWriter

_log = logging.getLogger(__name__)
IntArray = npt.NDArray[np.int64]
_INT64_MAX = (1 << 63) - 1


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
    problems: list[str] = field(default_factory=list)  # what was skipped (at most 20 entries)
    problem_count: int = 0

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
                    index=_typed(start.get("episode", len(found)), int, len(found)),
                    start_ns=int(start["log_ns"]),
                    end_ns=end.get("log_ns"),
                    scenario=_typed(start.get("scenario"), str),
                    seed=_typed(start.get("seed"), int),
                    steps=_typed(end.get("steps"), int),
                    episode_return=_typed(end.get("return"), float),
                    reason=_typed(end.get("reason"), str),
                    drawn=_drawn(start.get("drawn")),
                )
            )
        start = event if kind == "episode_start" and "log_ns" in event else None
    return found


def _typed(value: Any, kind: type[Any], default: Any = None) -> Any:
    """``value`` if it has the JSON type ``kind`` (an int passes as a float), else ``default``."""
    if isinstance(value, bool):
        return default
    if kind is float and isinstance(value, int):
        return float(value)
    return value if isinstance(value, kind) else default


def _drawn(value: Any) -> dict[str, float]:
    if not isinstance(value, dict):
        return {}
    return {str(k): float(v) for k, v in value.items() if _typed(v, float) is not None}


@dataclass
class _Raw:
    log_ns: list[int] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)


def read_recording(path: str | Path, limits: scan.Limits | None = None) -> Recording:
    """Read a recording (``.mcap``, or an unfinished or damaged one: everything readable).

    Whatever had to be skipped (a cut end, a chunk with a bad CRC, a decompression bomb) is
    listed in ``Recording.problems`` and logged as a warning; a file that is not MCAP at all
    raises :class:`RecordingError`.
    """
    path = Path(path)
    if not path.is_file():
        unfinished = path.with_name(path.name + PART_SUFFIX)
        hint = f"; an unfinished recording exists: {unfinished}" if unfinished.is_file() else ""
        raise scan.RecordingError(f"no recording at {path}{hint}")
    reading = scan.Scan(path, limits)
    try:
        return _read(path, reading)
    except MemoryError:
        pass  # leave the handler first: what the read held is freed with its frames, then say so
    raise reading.out_of_memory()


def _read(path: Path, reading: scan.Scan) -> Recording:
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    raw: dict[int, _Raw] = {}
    metadata: dict[str, dict[str, str]] = {}
    attachments: list[Attachment] = []
    header = None
    for record in reading.records():
        if isinstance(record, scan.Message):
            if record.log_time > _INT64_MAX:
                reading.problem(f"skipped a message with log time {record.log_time} ns (beyond int64)")
                continue
            found = raw.setdefault(record.channel_id, _Raw())
            found.log_ns.append(record.log_time)
            found.data.append(record.data)
        elif isinstance(record, scan.Schema):
            schemas.setdefault(record.id, record.name)
        elif isinstance(record, scan.Channel):
            channels.setdefault(record.id, (record.topic, record.schema_id))
        elif isinstance(record, scan.Metadata):
            metadata[record.name] = dict(record.metadata)
        elif isinstance(record, scan.Attachment):
            attachments.append(Attachment(record.name, record.media_type, record.data))
        elif isinstance(record, scan.Header) and header is None:
            header = record
    if header is None:
        raise scan.RecordingError(f"{path} holds no readable MCAP header: {'; '.join(reading.problems)}")
    series = _series(reading, raw, channels, schemas)
    counts = {topic: len(s) for topic, s in series.items()}
    return Recording(
        path,
        reading.complete,
        header.profile,
        header.library,
        series,
        metadata,
        attachments,
        counts,
        problems=reading.problems,
        problem_count=reading.problem_count,
    )


def _series(
    reading: scan.Scan, raw: dict[int, _Raw], channels: dict[int, tuple[str, int]], schemas: dict[int, str]
) -> dict[str, Series]:
    series: dict[str, Series] = {}
    for channel_id, messages in raw.items():
        if channel_id not in channels:
            reading.problem(
                f"skipped {len(messages.data)} message(s) of channel {channel_id}, which is not defined"
            )
            continue
        topic, schema_id = channels[channel_id]
        if topic in series:
            reading.problem(f"skipped {len(messages.data)} message(s) of a second channel named {topic!r}")
            continue
        series[topic] = _decode(reading, topic, schemas.get(schema_id, ""), messages)
    for topic, schema_id in channels.values():
        series.setdefault(topic, _decode(reading, topic, schemas.get(schema_id, ""), _Raw()))
    return series


def _decode(reading: scan.Scan, topic: str, msgtype: str, raw: _Raw) -> Series:
    """The messages of one channel as arrays; payloads that do not decode are skipped and reported."""
    decoder = _DECODERS.get(msgtype)
    if decoder is None:
        _log.info("channel %s has type %s, which fmu-bridge does not decode", topic, msgtype)
        log_ns = np.array(raw.log_ns, dtype=np.int64)
        return Series(topic, msgtype, [], log_ns, log_ns, np.zeros(0))
    if msgtype == cdr.JOINT_STATE:
        try:  # the common case: every message decodes (in one numpy call for a fixed layout)
            names, stamps, values = cdr.decode_joint_states(raw.data)
            log_ns = np.array(raw.log_ns, dtype=np.int64)
            return Series(topic, msgtype, names, log_ns, stamps, values)
        except BridgeError:
            pass
    keep = []
    for i, payload in enumerate(raw.data):
        try:
            decoder(payload)
        except BridgeError:
            continue
        keep.append(i)
    if len(keep) < len(raw.data):
        reading.problem(
            f"skipped {len(raw.data) - len(keep)} message(s) of {topic} that are not valid {msgtype}"
        )
    data = [raw.data[i] for i in keep]
    log_ns = np.array([raw.log_ns[i] for i in keep], dtype=np.int64)
    if msgtype == cdr.JOINT_STATE:
        names, stamps, values = cdr.decode_joint_states(data)
        return Series(topic, msgtype, names, log_ns, stamps, values)
    if msgtype == cdr.FLOAT64:
        values = np.array([cdr.decode_float64(d) for d in data], dtype=np.float64)
        return Series(topic, msgtype, [topic.strip("/")], log_ns, log_ns, values)
    texts = [cdr.decode_string(d) for d in data]
    return Series(topic, msgtype, [], log_ns, log_ns, np.zeros(0), texts)


_DECODERS: dict[str, Callable[[bytes], object]] = {
    cdr.JOINT_STATE: cdr.decode_joint_state,
    cdr.FLOAT64: cdr.decode_float64,
    cdr.STRING: cdr.decode_string,
}


def recovered_name(part: Path) -> Path:
    return part.with_name(part.name.removesuffix(PART_SUFFIX)) if part.name.endswith(PART_SUFFIX) else part


@dataclass(frozen=True)
class Recovered:
    """What ``recover_file`` wrote, and what it had to leave out."""

    path: Path
    messages: int
    problems: list[str]
    problem_count: int


def recover(
    part: str | Path,
    output: str | Path | None = None,
    *,
    overwrite: bool = False,
    limits: scan.Limits | None = None,
) -> Path:
    """Rewrite everything readable in an unfinished recording into a valid ``.mcap``; returns its path.

    See :func:`recover_file`.
    """
    return recover_file(part, output, overwrite=overwrite, limits=limits).path


def recover_file(
    part: str | Path,
    output: str | Path | None = None,
    *,
    overwrite: bool = False,
    limits: scan.Limits | None = None,
) -> Recovered:
    """Rewrite everything readable in an unfinished or damaged recording into a valid ``.mcap``.

    Args:
        part: the unfinished file (``NAME.mcap.part``); it is only read, never changed.
        output: where to write (default: ``NAME.mcap`` beside it).
        overwrite: replace ``output`` if it exists (only once the new file is complete).

    Messages keep their channel, log and publish times and sequence. Chunks that fail their
    CRC are left out and reported, never copied with a fresh CRC. The output is written to a
    temporary file beside it, synced and renamed; if writing fails (a full disk), the temporary
    file is removed, ``output`` and the input are untouched, and ``RecordingError`` says why.
    """
    source = Path(part)
    target = Path(output) if output is not None else recovered_name(source)
    _check_recover_paths(source, target, overwrite)
    first, schemas, channels = _definitions(source, limits)
    if first is None:
        raise scan.RecordingError(f"{source} holds no readable MCAP header: nothing to recover")
    reading = scan.Scan(source, limits)
    records = reading.records()
    work = target.with_name(f".{target.name}.{os.getpid()}.recovering")
    writer = McapWriter(target, profile=first.profile, library=first.library, work_path=work, overwrite=True)
    try:
        _copy(writer, records, schemas, channels, reading)
        writer.close()
    except (BridgeError, OSError) as exc:
        writer.abort()
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise scan.RecordingError(
            f"recover: writing {target} failed ({reason}); nothing was written and {source} is "
            "untouched: free some space or choose another --output"
        ) from exc
    _log.info("recovered %d messages from %s into %s", writer.message_count, source, target)
    return Recovered(target, writer.message_count, reading.problems, reading.problem_count)


def _check_recover_paths(source: Path, target: Path, overwrite: bool) -> None:
    if not source.is_file():
        raise scan.RecordingError(f"no file to recover at {source}")
    if target.resolve() == source.resolve() or (target.exists() and os.path.samefile(target, source)):
        raise scan.RecordingError(
            f"recover {source}: give an output name other than the input (e.g. NAME.mcap)"
        )
    if target.exists() and not overwrite:
        raise scan.RecordingError(f"{target} exists; pass --force to overwrite it")


def _definitions(
    source: Path, limits: scan.Limits | None
) -> tuple[scan.Header | None, dict[int, scan.Schema], dict[int, scan.Channel]]:
    """The header and every readable schema and channel (a first pass: the summary may define what a
    lost chunk did)."""
    header = None
    schemas: dict[int, scan.Schema] = {}
    channels: dict[int, scan.Channel] = {}
    for record in scan.Scan(source, limits).records():
        if isinstance(record, scan.Schema):
            schemas.setdefault(record.id, record)
        elif isinstance(record, scan.Channel):
            channels.setdefault(record.id, record)
        elif isinstance(record, scan.Header) and header is None:
            header = record
    return header, schemas, channels


def _copy(
    writer: McapWriter,
    records: Iterator[scan.Record],
    schemas: dict[int, scan.Schema],
    channels: dict[int, scan.Channel],
    reading: scan.Scan,
) -> None:
    schema_ids = {sid: writer.add_schema(s.name, s.encoding, s.data) for sid, s in schemas.items()}
    channel_ids = {
        cid: writer.add_channel(c.topic, schema_ids.get(c.schema_id, 0), c.message_encoding, c.metadata)
        for cid, c in channels.items()
    }
    # a payload the readers would skip (a flipped bit in an unchecked chunk) is left out here too,
    # so that what recover writes always reads clean
    decoders = {
        cid: _DECODERS.get(schemas[c.schema_id].name) if c.schema_id in schemas else None
        for cid, c in channels.items()
    }
    orphans, invalid = 0, Counter[int]()
    for record in records:
        if isinstance(record, scan.Message):
            if record.channel_id not in channel_ids:
                orphans += 1
                continue
            decoder = decoders[record.channel_id]
            if decoder is not None and not _decodes(decoder, record.data):
                invalid[record.channel_id] += 1
                continue
            writer.add_message(
                channel_ids[record.channel_id],
                record.log_time,
                record.data,
                publish_time=record.publish_time,
                sequence=record.sequence,
            )
        elif isinstance(record, scan.Metadata):
            writer.add_metadata(record.name, record.metadata)
        elif isinstance(record, scan.Attachment):
            writer.add_attachment(
                record.name,
                record.media_type,
                record.data,
                log_time=record.log_time,
                create_time=record.create_time,
            )
    if orphans:
        reading.problem(f"left out {orphans} message(s) of channels that are not defined")
    for cid, count in invalid.items():
        channel = channels[cid]
        msgtype = schemas[channel.schema_id].name
        reading.problem(f"left out {count} message(s) of {channel.topic} that are not valid {msgtype}")


def _decodes(decoder: Callable[[bytes], object], payload: bytes) -> bool:
    try:
        decoder(payload)
    except BridgeError:
        return False
    return True
