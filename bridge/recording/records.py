"""MCAP records as bytes, following the MCAP specification (major version 0).

Every record is ``<opcode uint8><content length uint64><content>``, little-endian. Strings are
``uint32`` byte length + UTF-8; maps are ``uint32`` byte length + entries; timestamps are
``uint64`` ns. Only the writer side lives here: reading is done by the ``mcap`` package.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass

MAGIC = b"\x89MCAP0\r\n"

HEADER = 0x01
FOOTER = 0x02
SCHEMA = 0x03
CHANNEL = 0x04
MESSAGE = 0x05
CHUNK = 0x06
MESSAGE_INDEX = 0x07
CHUNK_INDEX = 0x08
ATTACHMENT = 0x09
ATTACHMENT_INDEX = 0x0A
STATISTICS = 0x0B
METADATA = 0x0C
METADATA_INDEX = 0x0D
SUMMARY_OFFSET = 0x0E
DATA_END = 0x0F

RECORD_PREFIX = struct.Struct("<BQ")
MESSAGE_FIELDS = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time


def record(opcode: int, content: bytes) -> bytes:
    return RECORD_PREFIX.pack(opcode, len(content)) + content


def string(text: str) -> bytes:
    data = text.encode("utf-8")
    return struct.pack("<I", len(data)) + data


def string_map(mapping: Mapping[str, str]) -> bytes:
    body = b"".join(string(k) + string(v) for k, v in mapping.items())
    return struct.pack("<I", len(body)) + body


def u16_u64_map(mapping: Mapping[int, int]) -> bytes:
    body = b"".join(struct.pack("<HQ", k, v) for k, v in sorted(mapping.items()))
    return struct.pack("<I", len(body)) + body


def header(profile: str, library: str) -> bytes:
    return record(HEADER, string(profile) + string(library))


def footer(summary_start: int, summary_offset_start: int, summary_crc: int) -> bytes:
    return record(FOOTER, struct.pack("<QQI", summary_start, summary_offset_start, summary_crc))


def footer_crc_part(summary_start: int, summary_offset_start: int) -> bytes:
    """The footer bytes the summary CRC covers (everything before the CRC field)."""
    return RECORD_PREFIX.pack(FOOTER, 20) + struct.pack("<QQ", summary_start, summary_offset_start)


def schema(schema_id: int, name: str, encoding: str, data: bytes) -> bytes:
    return record(
        SCHEMA,
        struct.pack("<H", schema_id) + string(name) + string(encoding) + struct.pack("<I", len(data)) + data,
    )


def channel(channel_id: int, schema_id: int, topic: str, encoding: str, metadata: Mapping[str, str]) -> bytes:
    return record(
        CHANNEL,
        struct.pack("<HH", channel_id, schema_id) + string(topic) + string(encoding) + string_map(metadata),
    )


def message(channel_id: int, sequence: int, log_time: int, publish_time: int, data: bytes) -> bytes:
    return record(MESSAGE, MESSAGE_FIELDS.pack(channel_id, sequence, log_time, publish_time) + data)


def message_prefix(channel_id: int, payload_size: int) -> bytes:
    """Opcode, length and channel id of a message record whose payload size never changes."""
    return RECORD_PREFIX.pack(MESSAGE, MESSAGE_FIELDS.size + payload_size) + struct.pack("<H", channel_id)


def chunk(start: int, end: int, uncompressed_size: int, crc: int, *, compression: str, data: bytes) -> bytes:
    content = struct.pack("<QQQI", start, end, uncompressed_size, crc) + string(compression)
    return record(CHUNK, content + struct.pack("<Q", len(data)) + data)


def message_index(channel_id: int, entries: bytes) -> bytes:
    """``entries``: packed ``<QQ`` pairs of (log_time, offset in the uncompressed chunk)."""
    return record(MESSAGE_INDEX, struct.pack("<HI", channel_id, len(entries)) + entries)


@dataclass(frozen=True)
class ChunkInfo:
    """Where a chunk went in the file: the content of its Chunk Index record."""

    start: int
    end: int
    offset: int
    length: int
    index_offsets: dict[int, int]
    index_length: int
    compression: str
    compressed_size: int
    uncompressed_size: int

    def index_record(self) -> bytes:
        content = (
            struct.pack("<QQQQ", self.start, self.end, self.offset, self.length)
            + u16_u64_map(self.index_offsets)
            + struct.pack("<Q", self.index_length)
            + string(self.compression)
            + struct.pack("<QQ", self.compressed_size, self.uncompressed_size)
        )
        return record(CHUNK_INDEX, content)


def attachment(log_time: int, create_time: int, name: str, media_type: str, data: bytes) -> bytes:
    fields = (
        struct.pack("<QQ", log_time, create_time)
        + string(name)
        + string(media_type)
        + struct.pack("<Q", len(data))
        + data
    )
    return record(ATTACHMENT, fields + struct.pack("<I", zlib.crc32(fields)))


def attachment_index(
    offset: int, length: int, *, log_time: int, create_time: int, data_size: int, name: str, media_type: str
) -> bytes:
    content = struct.pack("<QQQQQ", offset, length, log_time, create_time, data_size)
    return record(ATTACHMENT_INDEX, content + string(name) + string(media_type))


def metadata(name: str, mapping: Mapping[str, str]) -> bytes:
    return record(METADATA, string(name) + string_map(mapping))


def metadata_index(offset: int, length: int, name: str) -> bytes:
    return record(METADATA_INDEX, struct.pack("<QQ", offset, length) + string(name))


@dataclass(frozen=True)
class Statistics:
    message_count: int
    schema_count: int
    channel_count: int
    attachment_count: int
    metadata_count: int
    chunk_count: int
    start: int
    end: int
    channel_counts: dict[int, int]

    def record(self) -> bytes:
        content = struct.pack(
            "<QHIIIIQQ",
            self.message_count,
            self.schema_count,
            self.channel_count,
            self.attachment_count,
            self.metadata_count,
            self.chunk_count,
            self.start,
            self.end,
        )
        return record(STATISTICS, content + u16_u64_map(self.channel_counts))


def summary_offset(opcode: int, start: int, length: int) -> bytes:
    return record(SUMMARY_OFFSET, struct.pack("<BQQ", opcode, start, length))


def data_end(crc: int) -> bytes:
    return record(DATA_END, struct.pack("<I", crc))
