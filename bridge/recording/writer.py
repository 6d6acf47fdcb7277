"""A minimal, fast MCAP writer: chunked, zstd-compressed, indexed, crash-tolerant.

Why not ``mcap.writer.Writer``: it costs ~3.7 us per message, and an env step records five.
Here records go straight into the chunk buffer (a ``bytearray``): single messages through
``add_message``, and the messages of many steps at once through ``add_steps`` (packed in bulk
into the chunk by :class:`bridge.recording.block.StepBlock`; ``add_block`` takes records packed
elsewhere). Full chunks are compressed (zstd), indexed and
appended by ``bridge.recording.sink``.

The file is written as ``NAME.mcap.part`` and renamed to ``NAME.mcap`` when ``close()`` has
written the summary and footer, so an unfinished file is obvious; everything up to its last
complete chunk is readable (``bridge.recording.reader``). ``flush()`` writes the current chunk at
once (recorders call it at episode ends). Layout: magic, header, then chunks (schemas,
channels, messages) each followed by its message indexes, interleaved with metadata and
attachment records; data end; a summary (schemas, channels, statistics, chunk, attachment
and metadata indexes, summary offsets); footer; magic.
"""

from __future__ import annotations

import atexit
import logging
import os
import weakref
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge import __version__
from bridge.errors import BridgeError
from bridge.recording import records as rec
from bridge.recording.block import FixedMessage, IndexEntries, StepBlock
from bridge.recording.sink import ChunkJob, Raw, Sink

_log = logging.getLogger(__name__)
PART_SUFFIX = ".part"
DEFAULT_CHUNK_SIZE = 128 * 1024

__all__ = ["PART_SUFFIX", "FixedMessage", "McapWriter", "StepBlock", "part_path"]


def part_path(path: Path) -> Path:
    return path.with_name(path.name + PART_SUFFIX)


@dataclass
class ChunkState:
    """The chunk being filled."""

    buffer: bytearray
    pos: int = 0
    blocks: list[tuple[int, bytes]] = field(default_factory=list)  # channel, packed index entries
    start: int = -1  # earliest log time in the chunk (-1: no message yet)
    end: int = 0


class McapWriter:
    """Writes one MCAP file; a context manager.

    Args:
        path: the final file name (``.mcap``); ``path + ".part"`` is written until ``close()``.
        profile: the MCAP profile (``ros2``: schemas ``ros2msg``, messages ``cdr``).
        chunk_size: uncompressed bytes per chunk; at most this much is lost if the process dies.
        compression: ``zstd`` or ``none``.
        level: the zstd level. -1 (zstd's first "fast" level): cart-pole recordings' 128 KiB
            chunks come out as small as at level 1 (0.1% to 1.4% smaller) and compress 8-15%
            faster; at -2 they grow by 6-17%.
        work_path: the file written until ``close()`` (default ``path + ".part"``).
        overwrite: replace an existing file (else an existing recording is an error).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        profile: str = "ros2",
        library: str = f"fmu-bridge {__version__}",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        level: int = -1,
        work_path: str | Path | None = None,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self.part_path = Path(work_path) if work_path is not None else part_path(self.path)
        if compression not in ("zstd", "none"):
            raise BridgeError(f"MCAP compression {compression!r} is not supported; use zstd or none")
        if not overwrite:
            _refuse_existing(self.path, self.part_path)
        try:
            self.part_path.parent.mkdir(parents=True, exist_ok=True)
            file = self.part_path.open("wb")
        except OSError as exc:
            raise BridgeError(f"cannot create the recording: {exc.strerror} [{self.part_path}]") from exc
        self._file = file
        self._sink = Sink(file, compression=compression, level=level)
        self.chunk_size = chunk_size
        self.chunk = ChunkState(bytearray(chunk_size))
        self._generic: dict[int, list[int]] = {}
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._summary_schemas: list[bytes] = []
        self._summary_channels: list[bytes] = []
        self._counts: Counter[int] = Counter()
        self._metadata_count = self._attachment_count = 0
        self.closed = False
        self._write(Raw(rec.MAGIC + rec.header(profile, library)))
        ref = weakref.ref(self)
        self._at_exit: Callable[[], None] = lambda: _close_ref(ref)
        atexit.register(self._at_exit)

    # -- registration ----------------------------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, data)
        if key not in self._schemas:
            self._schemas[key] = schema_id = len(self._schemas) + 1
            record = rec.schema(schema_id, name, encoding, data)
            self._summary_schemas.append(record)
            self._place(record)
        return self._schemas[key]

    def add_channel(
        self,
        topic: str,
        schema_id: int,
        message_encoding: str = "cdr",
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        channel_id = len(self._summary_channels) + 1
        record = rec.channel(channel_id, schema_id, topic, message_encoding, dict(metadata or {}))
        self._summary_channels.append(record)
        self._place(record)
        self._generic[channel_id] = []
        return channel_id

    # -- data ------------------------------------------------------------------------------------
    def add_message(
        self,
        channel_id: int,
        log_time: int,
        data: bytes,
        *,
        publish_time: int | None = None,
        sequence: int | None = None,
    ) -> None:
        """One message (general path, ~1 us plus the payload's own encoding)."""
        if sequence is None:
            sequence = self._counts[channel_id]
        self._counts[channel_id] += 1
        publish = log_time if publish_time is None else publish_time
        pos = self._place(rec.message(channel_id, sequence, log_time, publish, data))
        index = self._generic[channel_id]
        index.append(log_time)
        index.append(pos)
        self._extend(log_time, log_time)

    def add_block(self, data: bytes | bytearray, index: IndexEntries, bounds: tuple[int, int]) -> None:
        """Message records packed elsewhere (:class:`StepBlock`), with their index entries
        (offsets relative to ``data``) and (earliest, latest) log time; they go into one chunk."""
        pos = self._place(data)
        for _, pairs in index:
            pairs[:, 1] += pos
        self._add_indexed(index, bounds)

    def add_steps(
        self,
        block: StepBlock,
        times: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]],
        values: list[npt.NDArray[np.float64]],
    ) -> None:
        """``add_block(*block.pack(times, values))`` without the copy: ``block`` packs the steps'
        records straight into the chunk (one chunk; a new one when they do not fit in this one)."""
        size = len(times[0][0]) * block.size
        pos = self._reserve(size)
        index, bounds = block.pack_into(self.chunk.buffer, pos, times, values)
        self.chunk.pos = pos + size
        self._add_indexed(index, bounds)

    def _add_indexed(self, index: IndexEntries, bounds: tuple[int, int]) -> None:
        """Index entries (offsets in the chunk) of records placed in it, and their time bounds."""
        chunk = self.chunk
        for channel_id, pairs in index:
            chunk.blocks.append((channel_id, pairs.tobytes()))
            self._counts[channel_id] += len(pairs)
        self._extend(*bounds)

    @property
    def room(self) -> int:
        """Bytes left in the current chunk; a larger record starts the next chunk."""
        return self.chunk_size - self.chunk.pos

    def _extend(self, start: int, end: int) -> None:
        chunk = self.chunk
        if chunk.start < 0 or start < chunk.start:
            chunk.start = start
        chunk.end = max(chunk.end, end)

    def _place(self, record: bytes | bytearray) -> int:
        """Put a record into the current chunk; returns its position there."""
        pos = self._reserve(len(record))
        self.chunk.buffer[pos : pos + len(record)] = record
        self.chunk.pos = pos + len(record)
        return pos

    def _reserve(self, size: int) -> int:
        """Where ``size`` bytes go in the current chunk (the next chunk when they do not fit,
        unless this one is empty; the buffer grows for a record larger than a chunk)."""
        self._check_open()
        chunk = self.chunk
        if chunk.pos and chunk.pos + size > self.chunk_size:
            self.rotate()
        pos = chunk.pos
        if pos + size > len(chunk.buffer):
            chunk.buffer.extend(bytes(pos + size - len(chunk.buffer)))
        return pos

    def add_metadata(self, name: str, mapping: Mapping[str, str]) -> None:
        """A Metadata record (name and string pairs) in the data section."""
        self._check_open()
        self.rotate()
        self._metadata_count += 1
        self._write(Raw(rec.metadata(name, mapping), kind="metadata", name=name))

    def add_attachment(
        self, name: str, media_type: str, data: bytes, *, log_time: int = 0, create_time: int = 0
    ) -> None:
        """An Attachment record (a file carried along, e.g. the experiment file)."""
        self._check_open()
        self.rotate()
        self._attachment_count += 1
        record = rec.attachment(log_time, create_time, name, media_type, data)
        self._write(
            Raw(
                record,
                kind="attachment",
                name=name,
                log_time=log_time,
                create_time=create_time,
                media_type=media_type,
                data_size=len(data),
            )
        )

    def rotate(self) -> None:
        """Compress, index and write the current chunk (if it holds anything); start a new one."""
        chunk = self.chunk
        if not chunk.pos:
            return
        start, end = (chunk.start, chunk.end) if chunk.start >= 0 else (0, 0)
        self._write(ChunkJob(chunk.buffer, chunk.pos, start, end, self._generic, chunk.blocks))
        self._generic = {channel_id: [] for channel_id in self._generic}
        chunk.pos, chunk.start, chunk.end = 0, -1, 0  # the buffer is written: reuse it
        chunk.blocks = []

    def flush(self) -> None:
        """Write the current chunk and flush the file (no fsync): a crash now loses nothing."""
        self._check_open()
        self.rotate()
        try:
            self._file.flush()
        except OSError as exc:  # a full disk shows here first: buffered writes succeeded
            raise self._failed(exc) from exc

    # -- end -------------------------------------------------------------------------------------
    def close(self) -> Path:
        """Finish the file (summary, footer) and rename it from ``.part``; returns the final path."""
        if self.closed:
            return self.path
        self.closed = True
        atexit.unregister(self._at_exit)
        try:
            self.rotate()
            self._write_summary()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            os.replace(self.part_path, self.path)
        except OSError as exc:
            _close_quietly(self._file)
            raise BridgeError(
                f"finishing the recording failed: {exc.strerror or exc}; what was written so far is in "
                f"{self.part_path} (`fmu-bridge recover` rewrites its readable part)"
            ) from exc
        finally:
            _close_quietly(self._file)
        _log.info("wrote %s (%d messages)", self.path, self.message_count)
        return self.path

    def abort(self) -> None:
        """Stop writing and delete the unfinished file (nothing is renamed to ``path``)."""
        self.closed = True
        atexit.unregister(self._at_exit)
        _close_quietly(self._file)
        self.part_path.unlink(missing_ok=True)

    @property
    def message_count(self) -> int:
        return sum(self._counts.values())

    def _write_summary(self) -> None:
        chunks = self._sink.chunks
        with_messages = [c for c in chunks if c.index_offsets]
        stats = rec.Statistics(
            message_count=self.message_count,
            schema_count=len(self._summary_schemas),
            channel_count=len(self._summary_channels),
            attachment_count=self._attachment_count,
            metadata_count=self._metadata_count,
            chunk_count=len(chunks),
            start=min((c.start for c in with_messages), default=0),
            end=max((c.end for c in with_messages), default=0),
            channel_counts={k: v for k, v in self._counts.items() if v},
        )
        self._sink.finish(self._summary_schemas, self._summary_channels, stats)

    def _check_open(self) -> None:
        if self.closed:
            raise BridgeError(f"the recording {self.path} is closed; open a new one to record more")

    def _write(self, item: Raw | ChunkJob) -> None:
        try:
            item.write(self._sink)
        except OSError as exc:
            raise self._failed(exc) from exc

    def _failed(self, exc: OSError) -> BridgeError:
        """The one error of a failed write (a full disk, a file size limit, an I/O error)."""
        return BridgeError(
            f"writing the recording failed: {exc.strerror or exc}; free some space or record to "
            f"another folder; what was written so far is in {self.part_path} (`fmu-bridge recover` "
            "rewrites its readable part)"
        )

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _refuse_existing(path: Path, part: Path) -> None:
    if part.exists():
        raise BridgeError(
            f"an unfinished recording is in the way: recover it (`fmu-bridge recover {part}`), move it "
            f"or delete it [{part}]"
        )
    if path.exists():
        raise BridgeError(f"a recording exists at {path}; choose another name or pass --force to replace it")


def _close_quietly(file: Any) -> None:
    """Close a file whose writes may have failed (closing flushes, and may fail the same way)."""
    try:
        file.close()
    except OSError:
        _log.debug("closing %s failed", getattr(file, "name", file), exc_info=True)


def _close_ref(ref: weakref.ReferenceType[McapWriter]) -> None:
    """At interpreter exit, finish a recording the program forgot to close."""
    writer = ref()
    if writer is not None and not writer.closed:
        try:
            writer.close()
        except BridgeError as exc:
            _log.error("%s", exc)
