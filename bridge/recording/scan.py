"""A bounded MCAP reader: records of any file, however cut or corrupt, with what was skipped.

Why not the ``mcap`` package's ``StreamReader``: on a cut or corrupt file it raises
``struct.error``, ``ZstdError``, ``KeyError`` and others from deep inside, it accepts chunks
whose CRC does not match, and it allocates a chunk's declared uncompressed size before
decompressing (a 33 KB file declaring gigabytes takes gigabytes). Here every length is
checked against what is left (of the file, the record, the chunk) before it is used; a chunk's
declared size is checked against :class:`Limits` before anything is allocated and it is
decompressed with a bounded read; CRCs (chunk, attachment, data section, summary) are checked.
Whatever cannot be read is skipped and described in ``Scan.problems``; reading goes on where
that is safe (after a bad chunk or record of known length) and stops where it is not (a
length that runs past the end of the file: the file is cut there).
"""

from __future__ import annotations

import io
import logging
import os
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from bridge.errors import BridgeError
from bridge.recording import records as rec

_log = logging.getLogger(__name__)
_MIB = 1 << 20
_MAX_PROBLEMS = 20


class RecordingError(BridgeError):
    """A recording cannot be read at all (not MCAP, no header), or cannot be written."""


@dataclass(frozen=True)
class Limits:
    """What one read may take, whatever the file's size.

    A chunk compressed more than ``chunk_ratio`` to one is skipped unread (recordings compress
    tens to one; a megabyte of file declaring gigabytes of tiny messages is a bomb); the whole
    read stops with a RecordingError past ``inflate_bytes`` decompressed, ``messages`` messages or
    ``time_s`` seconds.

    Args:
        record_bytes: the largest record read into memory (a chunk, an attachment).
        chunk_bytes: the largest declared uncompressed chunk size accepted.
        chunk_ratio: the largest declared uncompressed size per compressed byte of a chunk.
        inflate_bytes: decompressed bytes allowed in total.
        messages: messages allowed in total.
        time_s: seconds one read may take.
    """

    record_bytes: int = 256 * _MIB
    chunk_bytes: int = 32 * _MIB
    chunk_ratio: int = 1000
    inflate_bytes: int = 2048 * _MIB
    messages: int = 20_000_000
    time_s: float = 120.0


@dataclass(frozen=True)
class Header:
    profile: str
    library: str


@dataclass(frozen=True)
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class Message:
    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


@dataclass(frozen=True)
class Metadata:
    name: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class Attachment:
    log_time: int
    create_time: int
    name: str
    media_type: str
    data: bytes


Record = Header | Schema | Channel | Message | Metadata | Attachment


class _Corrupt(Exception):
    """A record's fields do not fit in it."""


class _Fields:
    """Reads little-endian fields from one record's content, never past its end."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data = memoryview(data)
        self.pos = 0

    def take(self, fmt: struct.Struct) -> tuple[int, ...]:
        if self.pos + fmt.size > len(self.data):
            raise _Corrupt(f"a field needs {fmt.size} bytes at {self.pos}, the record has {len(self.data)}")
        values = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return values

    def raw(self, length: int) -> bytes:
        if length > len(self.data) - self.pos:
            raise _Corrupt(f"a field declares {length} bytes, {len(self.data) - self.pos} remain")
        start, self.pos = self.pos, self.pos + length
        return bytes(self.data[start : self.pos])

    def string(self) -> str:
        return self.raw(self.take(_U32)[0]).decode("utf-8", "replace")

    def string_map(self) -> dict[str, str]:
        inner = _Fields(self.raw(self.take(_U32)[0]))
        found = {}
        while inner.pos < len(inner.data):
            key = inner.string()
            found[key] = inner.string()
        return found

    def rest(self) -> bytes:
        return self.raw(len(self.data) - self.pos)


_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MESSAGE = struct.Struct("<HIQQ")
_CHUNK = struct.Struct("<QQQI")
_TIMES = struct.Struct("<QQ")
_FOOTER = struct.Struct("<QQI")


def parse(opcode: int, content: bytes | memoryview) -> Record | None:
    """The record of ``opcode`` (None for the kinds a reader does not need); ``_Corrupt`` if bad."""
    f = _Fields(content)
    if opcode == rec.MESSAGE:
        channel_id, sequence, log_time, publish_time = f.take(_MESSAGE)
        return Message(channel_id, sequence, log_time, publish_time, f.rest())
    if opcode == rec.SCHEMA:
        schema_id = f.take(_U16)[0]
        name, encoding = f.string(), f.string()
        return Schema(schema_id, name, encoding, f.raw(f.take(_U32)[0]))
    if opcode == rec.CHANNEL:
        channel_id, schema_id = f.take(_U16)[0], f.take(_U16)[0]
        return Channel(channel_id, schema_id, f.string(), f.string(), f.string_map())
    if opcode == rec.METADATA:
        return Metadata(f.string(), f.string_map())
    if opcode == rec.ATTACHMENT:
        log_time, create_time = f.take(_TIMES)
        name, media_type = f.string(), f.string()
        data = f.raw(f.take(_U64)[0])
        (crc,) = f.take(_U32)
        if crc and crc != zlib.crc32(content[: f.pos - 4]):
            raise _Corrupt(f"attachment {name!r}: CRC mismatch")
        return Attachment(log_time, create_time, name, media_type, data)
    if opcode == rec.HEADER:
        return Header(f.string(), f.string())
    return None


class Scan:
    """One pass over an MCAP file: ``for record in Scan(path).records(): ...``.

    After the pass, ``complete`` says whether the file ended with a footer and the closing
    magic, and ``problems`` describes everything skipped (at most 20 entries; ``problem_count``
    counts them all).
    """

    def __init__(self, path: str | Path, limits: Limits | None = None) -> None:
        self.path = Path(path)
        self.limits = limits or Limits()
        self.complete = False
        self.problems: list[str] = []
        self.problem_count = 0
        self.skipped_chunks = 0
        self._inflated = 0
        self._messages = 0
        self._deadline = time.monotonic() + self.limits.time_s

    def problem(self, text: str) -> None:
        self.problem_count += 1
        if len(self.problems) < _MAX_PROBLEMS:
            self.problems.append(text)
            _log.warning("%s: %s", self.path, text)

    def records(self) -> Iterator[Record]:
        """The records of the data section (chunks expanded), then the summary's schemas and channels."""
        try:
            stream = self.path.open("rb")
        except OSError as exc:
            raise RecordingError(f"cannot open the recording: {exc.strerror} [{self.path}]") from exc
        with stream:
            size = os.fstat(stream.fileno()).st_size
            magic = stream.read(len(rec.MAGIC))
            if magic != rec.MAGIC:
                what = "is empty" if not magic else f"starts with {magic[:8].hex(' ')}"
                cut = " (cut inside the magic)" if magic and rec.MAGIC.startswith(magic) else ""
                raise RecordingError(
                    f"not an MCAP file: it {what}{cut}, an MCAP file starts with "
                    f"{rec.MAGIC.hex(' ')} [{self.path}]"
                )
            try:
                yield from self._body(stream, size)
            except MemoryError:
                pass  # leave the handler first: the chunk that did not fit is freed with its frame
            else:
                return
        raise self.out_of_memory()

    def out_of_memory(self) -> RecordingError:
        """The error for a MemoryError met while reading (here or by whoever keeps the records)."""
        return RecordingError(
            f"reading ran out of memory after {self._messages:,} messages ({self._inflated:,} bytes "
            "decompressed): the recording holds more than this process may allocate; free memory, "
            f"raise the process's memory limit (ulimit -v), or read it on a larger machine [{self.path}]"
        )

    def _body(self, stream: io.BufferedReader, size: int) -> Iterator[Record]:
        data_crc = zlib.crc32(rec.MAGIC)
        summary_crc: int | None = None  # running once the data section has ended
        pos = len(rec.MAGIC)
        while True:
            prefix = stream.read(rec.RECORD_PREFIX.size)
            if len(prefix) < rec.RECORD_PREFIX.size:
                self._ended(pos, size, bool(prefix))
                return
            opcode, length = rec.RECORD_PREFIX.unpack(prefix)
            if length > size - pos - len(prefix):
                self.problem(
                    f"the record at byte {pos} (opcode 0x{opcode:02x}) declares {length} bytes, "
                    f"only {size - pos - len(prefix)} follow: the file is cut or corrupt there; read up to it"
                )
                return
            if length > self.limits.record_bytes:
                self.problem(f"skipped a {length}-byte record at byte {pos}: larger than the read limit")
                stream.seek(length, io.SEEK_CUR)
                pos += len(prefix) + length
                continue
            content = stream.read(length)
            if opcode == rec.FOOTER:
                self._footer(content, prefix, summary_crc, stream)
                return
            if opcode == rec.DATA_END and summary_crc is None:
                self._data_end(content, data_crc, pos)
                summary_crc = 0
            elif summary_crc is None:
                data_crc = zlib.crc32(content, zlib.crc32(prefix, data_crc))
            else:
                summary_crc = zlib.crc32(content, zlib.crc32(prefix, summary_crc))
            if opcode == rec.CHUNK:
                yield from self._chunk(content, pos)
            elif opcode != rec.DATA_END and (summary_crc is None or opcode in (rec.SCHEMA, rec.CHANNEL)):
                if opcode == rec.MESSAGE:
                    self._count_message()
                yield from self._one(opcode, content, pos)
            pos += len(prefix) + length

    def _one(self, opcode: int, content: bytes | memoryview, pos: int) -> Iterator[Record]:
        try:
            found = parse(opcode, content)
        except _Corrupt as exc:
            self.problem(f"skipped a corrupt record (opcode 0x{opcode:02x}) at byte {pos}: {exc}")
            return
        if found is not None:
            yield found

    def _ended(self, pos: int, size: int, partial: bool) -> None:
        tail = f", {size - pos} byte(s) of a record prefix" if partial else ""
        self.problem(f"the file ends at byte {size} without a footer{tail}: it is unfinished or cut")

    def _data_end(self, content: bytes, data_crc: int, pos: int) -> None:
        stored = _Fields(content).take(_U32)[0] if len(content) >= 4 else 0
        if stored and stored != data_crc:
            self.problem(
                f"data section CRC mismatch (stored {stored:08x}, computed {data_crc:08x}, data end at "
                f"byte {pos}): some bytes outside the chunks were changed"
            )

    def _footer(
        self, content: bytes, prefix: bytes, summary_crc: int | None, stream: io.BufferedReader
    ) -> None:
        try:
            summary_start, _, stored = _Fields(content).take(_FOOTER)
        except _Corrupt:
            self.problem("the footer is corrupt")
            return
        if summary_crc is not None and summary_start and stored:
            computed = zlib.crc32(content[:16], zlib.crc32(prefix, summary_crc))
            if computed != stored:
                self.problem(
                    f"summary CRC mismatch (stored {stored:08x}, computed {computed:08x}): readers that "
                    "use the index may fail; `fmu-bridge recover` rewrites it"
                )
        if stream.read(len(rec.MAGIC)) != rec.MAGIC:
            self.problem("the footer is not followed by the closing MCAP magic: the file is cut or corrupt")
            return
        self.complete = True

    def _chunk(self, content: bytes, pos: int) -> Iterator[Record]:
        records = self._expand(content, pos)
        if records is None:
            self.skipped_chunks += 1
            return
        inner = memoryview(records)
        at = 0
        while at < len(inner):
            if len(inner) - at < rec.RECORD_PREFIX.size:
                self.problem(f"the chunk at byte {pos} ends inside a record prefix; read up to it")
                return
            opcode, length = rec.RECORD_PREFIX.unpack_from(inner, at)
            at += rec.RECORD_PREFIX.size
            if opcode not in (rec.SCHEMA, rec.CHANNEL, rec.MESSAGE) or length > len(inner) - at:
                self.problem(
                    f"the chunk at byte {pos} holds a bad record at {at - 9} (opcode 0x{opcode:02x}, "
                    f"{length} bytes); skipped the rest of the chunk"
                )
                return
            if opcode == rec.MESSAGE:
                self._count_message()
            yield from self._one(opcode, inner[at : at + length], pos)
            at += length

    def _count_message(self) -> None:
        self._messages += 1
        if self._messages > self.limits.messages:
            self._over(f"holds more than {self.limits.messages:,} messages")
        if not self._messages & 0xFFFF:
            self._check_time()

    def _check_time(self) -> None:
        if time.monotonic() > self._deadline:
            self._over(
                f"took longer than {self.limits.time_s:g} s to read ({self._messages:,} messages so far)"
            )

    def _over(self, what: str) -> None:
        raise RecordingError(
            f"the recording {what}: beyond this read's budget ({self.limits.messages:,} messages, "
            f"{self.limits.inflate_bytes:,} decompressed bytes, {self.limits.time_s:g} s); a bomb, or a "
            f"recording to read with larger bridge.recording.scan.Limits [{self.path}]"
        )

    def _expand(self, content: bytes, pos: int) -> bytes | None:
        """The chunk's records, decompressed within the limits and CRC-checked; None if unusable."""
        try:
            f = _Fields(content)
            _, _, declared, crc = f.take(_CHUNK)
            compression = f.string()
            data = f.raw(f.take(_U64)[0])
        except _Corrupt as exc:
            self.problem(f"skipped the corrupt chunk at byte {pos}: {exc}")
            return None
        self._check_time()
        if declared > self.limits.chunk_bytes or declared > self.limits.chunk_ratio * max(len(data), 1):
            self.problem(
                f"skipped the chunk at byte {pos}: it declares {declared} uncompressed bytes in "
                f"{len(data)} (limits: {self.limits.chunk_bytes} bytes, {self.limits.chunk_ratio} to one): "
                "corrupt, or a decompression bomb"
            )
            return None
        if self._inflated + declared > self.limits.inflate_bytes:
            self._over(f"decompresses to more than {self.limits.inflate_bytes:,} bytes")
        self._inflated += declared
        try:
            records = _decompress(compression, data, declared)
        except _Corrupt as exc:
            self.problem(f"skipped the chunk at byte {pos}: {exc}")
            return None
        if crc and zlib.crc32(records) != crc:
            self.problem(
                f"skipped the chunk at byte {pos}: CRC mismatch (stored {crc:08x}, computed "
                f"{zlib.crc32(records):08x}); its messages are lost"
            )
            return None
        return records


def _decompress(compression: str, data: bytes, declared: int) -> bytes:
    """Decompress reading at most ``declared + 1`` bytes, so a lying size cannot allocate more."""
    try:
        if compression == "":
            out = data
        elif compression == "zstd":
            import zstandard

            reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True)
            out = reader.read(declared + 1) if declared else reader.read(1)
        elif compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=declared + 1)
        else:
            raise _Corrupt(f"unknown compression {compression[:40]!r} (known: zstd, lz4, none)")
    except (_Corrupt, MemoryError):
        raise
    except Exception as exc:  # zstandard.ZstdError, lz4's RuntimeError: the data are corrupt
        if "alloc" in str(exc).lower():  # the library's own allocation failed: memory, not the file
            raise MemoryError(str(exc)) from None
        raise _Corrupt(f"{compression} data are corrupt ({type(exc).__name__}: {exc})") from exc
    if len(out) != declared:
        more = "+" if len(out) > declared else ""
        raise _Corrupt(f"it declares {declared} uncompressed bytes, decompression gave {len(out)}{more}")
    return bytes(out)
