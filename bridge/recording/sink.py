"""Where an MCAP file's bytes go: chunks compressed and indexed, records appended in order.

``Sink`` appends to the file and keeps what the summary needs: file offsets, the data-section
CRC, chunk, metadata and attachment index entries. A chunk is written together with its
message indexes in one ``write``, so a file cut at any moment ends after a whole chunk or
inside the last one (the part a stream reader drops).

Chunks are compressed in the recording thread. A background thread was measured and dropped:
zstd releases the GIL, but handing the GIL back and forth around it cost the stepping loop as
much as the compression it saved (~0.8 us per step, cart-pole, zstd level 1 then), and doing it
here means ``flush()`` has written the data to the OS when it returns.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import IO

from bridge.recording import records as rec


@dataclass
class Raw:
    """Records written as they are (header, metadata, attachment); ``kind`` says what to index."""

    data: bytes
    kind: str = ""
    name: str = ""
    log_time: int = 0
    create_time: int = 0
    media_type: str = ""
    data_size: int = 0

    def write(self, sink: Sink) -> None:
        offset = sink.append(self.data)
        if self.kind == "metadata":
            sink.metadata_index.append(rec.metadata_index(offset, len(self.data), self.name))
        elif self.kind == "attachment":
            sink.attachment_index.append(
                rec.attachment_index(
                    offset,
                    len(self.data),
                    log_time=self.log_time,
                    create_time=self.create_time,
                    data_size=self.data_size,
                    name=self.name,
                    media_type=self.media_type,
                )
            )


@dataclass
class ChunkJob:
    """One full chunk: the uncompressed records and what is needed to index them."""

    buffer: bytearray
    size: int
    start: int  # earliest and latest log time of its messages (0, 0 without messages)
    end: int
    generic: dict[int, list[int]]  # channel -> flat [log_time, offset, ...] of single messages
    blocks: list[tuple[int, bytes]] = field(default_factory=list)  # channel -> packed (log_time, offset)

    def index_records(self) -> list[tuple[int, bytes]]:
        """One Message Index record per channel with messages in this chunk, by channel id."""
        entries: dict[int, list[bytes]] = {}
        for channel_id, flat in self.generic.items():
            if flat:
                entries.setdefault(channel_id, []).append(struct.pack(f"<{len(flat)}Q", *flat))
        for channel_id, packed in self.blocks:
            entries.setdefault(channel_id, []).append(packed)
        return [(ch, rec.message_index(ch, b"".join(parts))) for ch, parts in sorted(entries.items())]

    def write(self, sink: Sink) -> None:
        data = memoryview(self.buffer)[: self.size]
        indexes = self.index_records()
        payload = sink.compress(data)
        crc = zlib.crc32(data)
        chunk = rec.chunk(self.start, self.end, self.size, crc, compression=sink.compression, data=payload)
        offset = sink.append(b"".join([chunk, *(record for _, record in indexes)]))  # one write
        offsets, position = {}, offset + len(chunk)
        for channel_id, record in indexes:
            offsets[channel_id] = position
            position += len(record)
        sink.chunks.append(
            rec.ChunkInfo(
                start=self.start,
                end=self.end,
                offset=offset,
                length=len(chunk),
                index_offsets=offsets,
                index_length=position - offset - len(chunk),
                compression=sink.compression,
                compressed_size=len(payload),
                uncompressed_size=self.size,
            )
        )


class Sink:
    """Appends records to ``file``, tracking offsets and the data-section CRC."""

    def __init__(self, file: IO[bytes], *, compression: str, level: int) -> None:
        self.file = file
        self.compression = "zstd" if compression == "zstd" else ""
        self._compressor = None
        if self.compression:
            import zstandard

            self._compressor = zstandard.ZstdCompressor(level=level)
        self.offset = 0
        self.crc = 0
        self.chunks: list[rec.ChunkInfo] = []
        self.metadata_index: list[bytes] = []
        self.attachment_index: list[bytes] = []

    def compress(self, data: memoryview) -> bytes:
        return self._compressor.compress(data) if self._compressor is not None else bytes(data)

    def append(self, data: bytes) -> int:
        """Write ``data``; returns the file offset it starts at."""
        offset = self.offset
        self.file.write(data)
        self.crc = zlib.crc32(data, self.crc)
        self.offset += len(data)
        return offset

    def finish(self, schemas: list[bytes], channels: list[bytes], statistics: rec.Statistics) -> None:
        """Data end, the summary section (grouped by opcode, with summary offsets), footer, magic."""
        self.append(rec.data_end(self.crc))
        groups = [
            (rec.SCHEMA, schemas),
            (rec.CHANNEL, channels),
            (rec.STATISTICS, [statistics.record()]),
            (rec.CHUNK_INDEX, [c.index_record() for c in self.chunks]),
            (rec.ATTACHMENT_INDEX, self.attachment_index),
            (rec.METADATA_INDEX, self.metadata_index),
        ]
        summary_start = self.offset
        summary, offsets = bytearray(), bytearray()
        for opcode, records in groups:
            if records:
                block = b"".join(records)
                offsets += rec.summary_offset(opcode, summary_start + len(summary), len(block))
                summary += block
        offsets_start = summary_start + len(summary)
        summary += offsets
        crc = zlib.crc32(rec.footer_crc_part(summary_start, offsets_start), zlib.crc32(summary))
        self.file.write(bytes(summary) + rec.footer(summary_start, offsets_start, crc) + rec.MAGIC)
