"""The wire frames: values round-trip bit for bit on both encoding paths (a list and an array),
decoding agrees with numpy's reading of the same bytes, and malformed frames are refused."""

from __future__ import annotations

import struct
from collections.abc import Iterable

import numpy as np
import pytest

from bridge.errors import TransportError
from bridge.net import protocol as proto

SPECIAL = [0.0, -0.0, 1.5, -2.25e300, 5e-324, 1e-310, float("inf"), float("-inf"), float("nan")]


def bits(values: Iterable[float]) -> list[bytes]:
    return [struct.pack("<d", v) for v in values]


@pytest.mark.parametrize("n", [0, 1, 3, len(SPECIAL)])
def test_values_round_trip_bit_for_bit_from_a_list_and_from_an_array(n: int) -> None:
    values = SPECIAL[:n]
    from_list = proto.encode_values(proto.ACTION, 7, 42, 99, values, flags=proto.SAVE_STATE)
    from_array = proto.encode_values(proto.ACTION, 7, 42, 99, np.array(values), flags=proto.SAVE_STATE)
    assert from_list == from_array
    frame = proto.decode(from_list, expected_values=n)
    assert (frame.kind, frame.episode, frame.step, frame.sim_time_ns, frame.flags) == (
        proto.ACTION, 7, 42, 99, proto.SAVE_STATE,
    )  # fmt: skip
    assert bits(frame.floats) == bits(values)
    assert frame.values.dtype == np.float64 and bits(frame.values.tolist()) == bits(values)
    # numpy's own reading of the payload is the independent reference
    reference = np.frombuffer(from_list, dtype="<f8", offset=proto.HEADER.size + proto.COUNT.size)
    assert bits(reference.tolist()) == bits(frame.floats)


def test_an_array_of_another_shape_or_type_is_sent_as_float64_in_c_order() -> None:
    grid = np.arange(6, dtype=np.float32).reshape(2, 3).T  # not C-contiguous, not float64
    frame = proto.decode(proto.encode_values(proto.OUTPUTS, 1, 1, 0, grid))
    assert frame.floats == (0.0, 3.0, 1.0, 4.0, 2.0, 5.0)


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"\x01\x01", "shorter than"),
        (proto.encode_values(proto.OUTPUTS, 1, 1, 0, [1.0])[:-3], "announces 1 values but carries 5 bytes"),
        (proto.encode_values(proto.OUTPUTS, 1, 1, 0, [1.0, 2.0]), "expected 1 values, got 2"),
        (b"\x02" + proto.encode_values(proto.OUTPUTS, 1, 1, 0, [1.0])[1:], "version 2"),
        (b"\x01\x09" + proto.encode_values(proto.OUTPUTS, 1, 1, 0, [1.0])[2:], "unknown frame kind 9"),
        (proto.encode_values(proto.OUTPUTS, 1, 1, 0, [1.0])[: proto.HEADER.size], "without a value count"),
    ],
)
def test_malformed_frames_are_refused_with_the_reason(payload: bytes, message: str) -> None:
    with pytest.raises(TransportError, match=message):
        proto.decode(payload, expected_values=1)


# -- PlainFrames: the one-call reading of a lockstep step's frames -------------------------------------
@pytest.mark.parametrize("kind", [proto.ACTION, proto.OUTPUTS])
@pytest.mark.parametrize("n", [0, 1, 3, len(SPECIAL)])
def test_plain_frames_read_what_decode_reads(kind: int, n: int) -> None:
    plain = proto.PlainFrames(kind, n)
    for flags in (0, proto.TERMINATED, proto.SAVE_STATE):
        written = proto.encode_values(kind, 7, 42, 12345, list(SPECIAL[:n]), flags=flags)
        assert written == proto.encode_values(kind, 7, 42, 12345, np.array(SPECIAL[:n]), flags=flags)
        fields, frame = plain.read(written), proto.decode(written, expected_values=n)
        assert fields is not None and fields[1:6] == (kind, flags, 7, 42, 12345)
        assert bits(fields[7:]) == bits(frame.floats) == bits(SPECIAL[:n])


def _action(client: int = 5, values: tuple[float, ...] = (1.0, 2.0)) -> bytes:
    return proto.encode_values(proto.ACTION, 1, 1, client, list(values))


@pytest.mark.parametrize(
    "payload",
    [
        _action(values=(1.0,)),  # another value count
        _action(values=(1.0, 2.0, 3.0)),
        _action()[:-1],  # cut short
        _action() + b"\x00",  # one byte too many
        b"\x02" + _action()[1:],  # another protocol version
        bytes([1, proto.OUTPUTS]) + _action()[2:],  # another kind
        proto.encode_message(proto.REJECT, 1, 1, 0, "x" * 20),  # a message of the same length
        b"",
    ],
)
def test_plain_frames_leave_every_other_payload_to_the_full_decoder(payload: bytes) -> None:
    plain = proto.PlainFrames(proto.ACTION, 2)
    assert plain.read(payload) is None
    assert plain.read(_action(client=-3)) is not None  # the same codec takes a plain one (the node
    # itself refuses negative client ids and flags, through the full path)
