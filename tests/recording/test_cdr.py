"""CDR packing against rosbags' serializer (the reference), and decoding of what rosbags writes."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bridge.net.ros2 import cdr

TS = get_typestore(Stores.ROS2_JAZZY)
JointState = TS.types[cdr.JOINT_STATE]
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]


def rosbags_joint_state(
    stamp_ns: int,
    names: list[str],
    position: np.ndarray,
    frame_id: str = "",
    velocity: np.ndarray | None = None,
) -> bytes:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    msg = JointState(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
        name=names,
        position=position,
        velocity=np.zeros(0) if velocity is None else velocity,
        effort=np.zeros(0),
    )
    return bytes(TS.serialize_cdr(msg, cdr.JOINT_STATE))


def random_case(rng: np.random.Generator) -> tuple[int, list[str], np.ndarray, str]:
    n = int(rng.integers(0, 7))
    names = ["n" * int(rng.integers(0, 9)) + f"{i}é"[: int(rng.integers(1, 3))] for i in range(n)]
    frame_id = "f" * int(rng.integers(0, 8))
    stamp = int(rng.integers(-(10**12), 10**12))
    return stamp, names, rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n), frame_id


def test_joint_state_layout_packs_exactly_what_rosbags_serializes() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):  # every alignment of names, frame ids and value counts
        stamp, names, values, frame_id = random_case(rng)
        expected = rosbags_joint_state(stamp, names, values, frame_id)
        layout = cdr.JointStateLayout.of(names, frame_id)
        assert layout.pack(stamp, values.tolist()) == expected
        assert layout.size == len(expected)
        assert cdr.encode_joint_state(stamp, names, values, frame_id=frame_id) == expected


def test_float64_and_string_equal_rosbags_bytes() -> None:
    float64, string = TS.types[cdr.FLOAT64], TS.types[cdr.STRING]
    for value in (0.0, -1.5, 1e-310, float("inf"), 123456.789):
        assert cdr.encode_float64(value) == bytes(TS.serialize_cdr(float64(data=value), cdr.FLOAT64))
    for text in ("", "a", "abcd", '{"event":"episode_start"}', "héllo"):
        assert cdr.encode_string(text) == bytes(TS.serialize_cdr(string(data=text), cdr.STRING))
        assert cdr.decode_string(cdr.encode_string(text)) == text


def test_decoders_read_rosbags_messages_including_velocities() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        stamp, names, values, frame_id = random_case(rng)
        velocity = rng.normal(size=int(rng.integers(0, 3)))
        decoded = cdr.decode_joint_state(rosbags_joint_state(stamp, names, values, frame_id, velocity))
        assert decoded.stamp_ns == stamp and decoded.frame_id == frame_id and decoded.name == names
        np.testing.assert_array_equal(decoded.position, values)
        np.testing.assert_array_equal(decoded.velocity, velocity)
    assert cdr.decode_float64(bytes(TS.serialize_cdr(TS.types[cdr.FLOAT64](data=2.5), cdr.FLOAT64))) == 2.5


def test_decode_joint_states_takes_the_fast_path_and_falls_back_for_changing_names() -> None:
    layout = cdr.JointStateLayout.of(["a", "bb"])
    payloads = [layout.pack(k * 20_000_000, [k * 0.5, -k]) for k in range(50)]
    names, stamps, values = cdr.decode_joint_states(payloads)
    assert names == ["a", "bb"]
    np.testing.assert_array_equal(stamps, np.arange(50) * 20_000_000)
    np.testing.assert_array_equal(values, np.column_stack([np.arange(50) * 0.5, -np.arange(50.0)]))
    mixed = [*payloads[:2], rosbags_joint_state(7, ["bb"], np.array([3.0]))]
    names, stamps, values = cdr.decode_joint_states(mixed)
    assert stamps.tolist() == [0, 20_000_000, 7]
    assert np.isnan(values[2, 0]) and values[2, 1] == 3.0


def test_foreign_encodings_are_refused_with_a_reason() -> None:
    big_endian = b"\x00\x00\x00\x00" + b"\x00" * 8
    with pytest.raises(Exception, match="little-endian CDR"):
        cdr.decode_float64(big_endian)
    with pytest.raises(Exception, match="payload ends"):
        cdr.decode_joint_state(cdr.ENCAPSULATION + b"\x01\x00")


def test_schema_texts_are_the_ros2_definitions_and_parse_back() -> None:
    text = cdr.schema_text(cdr.JOINT_STATE)
    assert text.startswith("std_msgs/Header header\nstring[] name\nfloat64[] position")
    assert "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec" in text  # ROS 2, not ROS 1 'time'
    parsed = get_types_from_msg(text, cdr.JOINT_STATE)
    assert cdr.JOINT_STATE in parsed and "std_msgs/msg/Header" in parsed
    assert cdr.schema_text(cdr.FLOAT64) == "float64 data\n"
