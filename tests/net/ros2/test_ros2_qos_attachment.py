"""The QoS string of tokens and the 33-byte attachment, byte for byte."""

from __future__ import annotations

import struct

import pytest
import zenoh
from zenoh import ext

from bridge.errors import ConfigError, TransportError
from bridge.net.ros2.attachment import Attachment
from bridge.net.ros2.qos import (
    DEFAULT,
    DURATION_INFINITE_NS,
    LATCHED,
    SENSOR_DATA,
    Durability,
    History,
    Liveliness,
    QoS,
    Reliability,
)


@pytest.mark.parametrize(
    ("qos", "expected"),
    [
        (QoS(depth=7), "::,7:,:,:,,"),  # design.md, talker publisher
        (QoS(depth=10), "::,10:,:,:,,"),  # design.md, listener subscription and services
        (QoS(depth=42), "::,:,:,:,,"),  # every field at rmw_zenoh's default
        (QoS(depth=0), "::,:,:,:,,"),  # depth 0 is adapted to 42
        (QoS(depth=5, reliability=Reliability.BEST_EFFORT), "2::,5:,:,:,,"),
        (QoS(depth=1, durability=Durability.TRANSIENT_LOCAL), ":1:,1:,:,:,,"),
        (QoS(depth=1000, history=History.KEEP_ALL), "::2,1000:,:,:,,"),
        (QoS(reliability=Reliability.SYSTEM_DEFAULT, durability=Durability.SYSTEM_DEFAULT), "::,10:,:,:,,"),
        (QoS(deadline_ns=1_500_000_000, lifespan_ns=2), "::,10:1,500000000:0,2:,,"),
        (QoS(liveliness=Liveliness.MANUAL_BY_TOPIC, liveliness_lease_ns=3_000_000_001), "::,10:,:,:3,3,1"),
        (QoS(deadline_ns=DURATION_INFINITE_NS), "::,10:,:,:,,"),
    ],
)
def test_qos_string_leaves_rmw_zenoh_defaults_empty(qos: QoS, expected: str) -> None:
    assert qos.to_keyexpr() == expected


@pytest.mark.parametrize("qos", [DEFAULT, SENSOR_DATA, LATCHED, QoS(deadline_ns=5, liveliness_lease_ns=7)])
def test_qos_string_parses_back(qos: QoS) -> None:
    assert QoS.from_keyexpr(qos.to_keyexpr()) == qos.adapted()


@pytest.mark.parametrize("bad", ["", "::,10:,:,:", "4::,10:,:,:,,", "::,x:,:,:,,", ":::,10:,:,:,,"])
def test_malformed_qos_strings_are_rejected(bad: str) -> None:
    with pytest.raises(ConfigError, match="rmw_zenoh's format"):
        QoS.from_keyexpr(bad)


def test_negative_depth_is_rejected() -> None:
    with pytest.raises(ConfigError, match="depth"):
        QoS(depth=-1)


# Research note, test vectors: seq 1, ts 1700000000000000000, GID 00..0f (33 bytes).
VECTOR = bytes.fromhex("010000000000000000002a36fe9c971710000102030405060708090a0b0c0d0e0f")


def test_attachment_bytes_match_the_documented_layout() -> None:
    attachment = Attachment(1, 1_700_000_000_000_000_000, bytes(range(16)))
    assert attachment.encode() == VECTOR
    assert len(VECTOR) == 33 and VECTOR[16] == 0x10
    assert struct.pack("<qqB16s", 1, 1_700_000_000_000_000_000, 16, bytes(range(16))) == VECTOR


def test_attachment_equals_zenoh_ext_serialization_as_zenoh_cpp_writes_it() -> None:
    serialized = ext.z_serialize((ext.Int64(1), ext.Int64(1_700_000_000_000_000_000), bytes(range(16))))
    assert serialized.to_bytes() == VECTOR
    seq, stamp, gid = ext.z_deserialize(tuple[ext.Int64, ext.Int64, bytes], zenoh.ZBytes(VECTOR))
    decoded = Attachment.decode(VECTOR)
    assert (decoded.sequence_number, decoded.source_timestamp_ns, decoded.gid) == (seq, stamp, gid)


def test_attachment_round_trips_negative_and_large_values() -> None:
    attachment = Attachment(2**63 - 1, -5, b"\xff" * 16)
    assert Attachment.decode(attachment.encode()) == attachment


# The labelled format of rmw_zenoh 0.2.0-0.2.3 (77 bytes); it must be recognised and refused.
LEGACY = bytes.fromhex(
    "0f73657175656e63655f6e756d6265720100000000000000"
    "10736f757263655f74696d657374616d7000002a36fe9c9717"
    "0a736f757263655f67696410000102030405060708090a0b0c0d0e0f"
)


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (None, "no attachment"),
        (b"", "no attachment"),
        (VECTOR[:32], "32 bytes, expected 33"),
        (VECTOR + b"\x00", "34 bytes, expected 33"),
        (VECTOR[:16] + b"\x0f" + VECTOR[17:], "length byte is 15"),
        (LEGACY, "0.2.0-0.2.3"),
    ],
)
def test_malformed_attachments_raise_transport_error_saying_why(raw: bytes | None, message: str) -> None:
    assert len(LEGACY) == 77
    with pytest.raises(TransportError, match=message):
        Attachment.decode(raw)


@pytest.mark.parametrize(
    ("seq", "stamp", "gid"), [(2**63, 0, bytes(16)), (1, 0, bytes(15)), (True, 0, bytes(16))]
)
def test_attachment_fields_are_validated_before_encoding(seq: int, stamp: int, gid: bytes) -> None:
    with pytest.raises(TransportError, match="attachment"):
        Attachment(seq, stamp, gid)
