"""The 33-byte attachment rmw_zenoh (Jazzy >= 0.2.4) puts on every sample, query and reply.

Little-endian, positional (zenoh-cpp's ext serializer):

======  ====  ==========================================================================
offset  size  content
======  ====  ==========================================================================
0       8     sequence number, int64 (per publisher or client, from 1, +1 per message)
8       8     source timestamp, int64 ns since the UNIX epoch
16      1     ``0x10``: the GID length (16) as a varint
17      16    GID of the publisher or client (``bridge.net.ros2.tokens.gid``)
======  ====  ==========================================================================

rmw_zenoh 0.2.0-0.2.3 used a 77-byte labelled format instead; a ROS subscriber drops a sample
without an attachment, and a malformed one may take the ROS process down, so only this exact
layout is ever produced.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

from bridge.errors import TransportError

GID_SIZE = 16
SIZE = 33
_LAYOUT = struct.Struct("<qqB16s")
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_LEGACY_SIZE = 77
_LEGACY_PREFIX = b"\x0fsequence_number"


@dataclass(frozen=True)
class Attachment:
    """What a ROS 2 sample carries besides its CDR payload.

    Attributes:
        sequence_number: per publisher (or client) counter; a reply repeats the request's.
        source_timestamp_ns: wall-clock time of sending, ns since the UNIX epoch.
        gid: the 16-byte GID of the sending publisher, or of the client a reply answers.
    """

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def __post_init__(self) -> None:
        for name in ("sequence_number", "source_timestamp_ns"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not _INT64_MIN <= value <= _INT64_MAX:
                raise TransportError(f"attachment {name} must be an int64, got {value!r}")
        if not isinstance(self.gid, bytes) or len(self.gid) != GID_SIZE:
            raise TransportError(
                f"attachment GID must be {GID_SIZE} bytes, got {len(self.gid)!r}: derive it with "
                "bridge.net.ros2.tokens.gid(token)"
            )

    @classmethod
    def now(cls, sequence_number: int, gid: bytes) -> Attachment:
        """An attachment stamped with the current wall-clock time."""
        return cls(sequence_number, time.time_ns(), gid)

    def encode(self) -> bytes:
        return _LAYOUT.pack(self.sequence_number, self.source_timestamp_ns, GID_SIZE, self.gid)

    @classmethod
    def decode(cls, data: bytes | None) -> Attachment:
        """Parse an attachment; anything but the 33-byte layout raises ``TransportError`` saying why."""
        if data is None or len(data) == 0:
            raise TransportError(
                "the sample has no attachment; rmw_zenoh (Jazzy >= 0.2.4) sends 33 bytes "
                "(sequence number, source timestamp, GID) with every message"
            )
        if len(data) != SIZE:
            raise TransportError(f"attachment of {len(data)} bytes, expected {SIZE}{_hint(data)}")
        seq, stamp, gid_len, gid = _LAYOUT.unpack(data)
        if gid_len != GID_SIZE:
            raise TransportError(
                f"attachment GID length byte is {gid_len}, expected {GID_SIZE}: not rmw_zenoh's layout "
                "(int64 seq, int64 timestamp, 0x10, 16-byte GID)"
            )
        return cls(seq, stamp, gid)


def _hint(data: bytes) -> str:
    if len(data) == _LEGACY_SIZE or data.startswith(_LEGACY_PREFIX):
        return (
            ": this is the labelled format of rmw_zenoh_cpp 0.2.0-0.2.3; upgrade the ROS side to "
            "ros-jazzy-rmw-zenoh-cpp >= 0.2.4"
        )
    return " (int64 seq, int64 timestamp, 0x10, 16-byte GID)"
