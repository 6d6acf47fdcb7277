"""CDR, the ROS 2 wire encoding, for the three standard messages a recording uses.

``sensor_msgs/msg/JointState`` carries every vector of named signals (observations, actions,
outputs, scenario draws): Rerun and Foxglove plot it natively, one series per name.
``std_msgs/msg/Float64`` carries the reward and ``std_msgs/msg/String`` (JSON) the episode
events. Payloads are little-endian CDR with the 4-byte encapsulation header; alignment counts
from the end of that header, and empty sequences add no padding (as rosbags writes them).

``JointStateLayout`` is the fast path: with fixed names only the stamp and the positions
change, so a message is a constant head and tail around ``sec, nanosec`` and ``n`` float64
values. The schema texts come from rosbags' Jazzy typestore.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, no options
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
STRING = "std_msgs/msg/String"
FloatArray = npt.NDArray[np.float64]


@cache
def schema_text(msgtype: str) -> str:
    """The ``ros2msg`` schema of a standard ROS 2 Jazzy type, with its dependencies appended."""
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype, ros_version=2)
    return str(text)


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` fields (sec, nanosec) of a time in ns (sec is floored)."""
    return divmod(stamp_ns, 1_000_000_000)


class _Builder:
    """Appends CDR fields with their alignment (relative to the end of the encapsulation header)."""

    def __init__(self) -> None:
        self.body = bytearray()

    def align(self, size: int) -> None:
        self.body += b"\x00" * (-len(self.body) % size)

    def u32(self, value: int) -> None:
        self.align(4)
        self.body += struct.pack("<I", value)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.body += data

    def doubles(self, values: Any) -> None:
        array = np.ascontiguousarray(values, dtype="<f8")
        self.u32(array.size)
        if array.size:
            self.align(8)
            self.body += array.tobytes()


def _head(frame_id: str, names: list[str] | tuple[str, ...]) -> _Builder:
    """A builder positioned after the stamp, holding frame_id and the names."""
    builder = _Builder()
    builder.body += b"\x00" * 8  # sec, nanosec: filled by the caller
    builder.string(frame_id)
    builder.u32(len(names))
    for name in names:
        builder.string(name)
    return builder


def encode_joint_state(
    stamp_ns: int,
    names: list[str] | tuple[str, ...],
    position: Any,
    *,
    velocity: Any = (),
    effort: Any = (),
    frame_id: str = "",
) -> bytes:
    """A ``sensor_msgs/msg/JointState`` payload (general form: any names and arrays)."""
    builder = _head(frame_id, names)
    struct.pack_into("<iI", builder.body, 0, *split_ns(stamp_ns))
    for values in (position, velocity, effort):
        builder.doubles(values)
    return ENCAPSULATION + bytes(builder.body)


def encode_float64(value: float) -> bytes:
    """A ``std_msgs/msg/Float64`` payload."""
    return ENCAPSULATION + struct.pack("<d", value)


def encode_string(text: str) -> bytes:
    """A ``std_msgs/msg/String`` payload."""
    builder = _Builder()
    builder.string(text)
    return ENCAPSULATION + bytes(builder.body)


@dataclass(frozen=True)
class JointStateLayout:
    """The byte layout of a JointState with fixed names and ``n`` positions (no velocity, effort).

    A payload is ``ENCAPSULATION, sec, nanosec, head, positions..., tail``: ``struct_format``
    describes it and ``pack`` builds one; ``bridge.recording.block`` lays the same parts out as a
    numpy record type to pack many at once.
    """

    names: tuple[str, ...]
    head: bytes
    tail: bytes

    @classmethod
    def of(cls, names: list[str] | tuple[str, ...], frame_id: str = "") -> JointStateLayout:
        builder = _head(frame_id, names)
        builder.u32(len(names))
        if names:
            builder.align(8)
        head = bytes(builder.body[8:])
        return cls(tuple(names), head, struct.pack("<II", 0, 0))  # empty velocity and effort

    @property
    def struct_format(self) -> str:
        return f"4siI{len(self.head)}s{len(self.names)}d{len(self.tail)}s"

    @property
    def size(self) -> int:
        return struct.calcsize("<" + self.struct_format)

    def pack(self, stamp_ns: int, values: Any) -> bytes:
        sec, nanosec = split_ns(stamp_ns)
        return struct.pack(
            "<" + self.struct_format, ENCAPSULATION, sec, nanosec, self.head, *values, self.tail
        )


class JointStateEncoder:
    """``JointStateEncoder(names).encode(stamp_ns, values)``: JointStates with fixed names, as bytes."""

    def __init__(self, names: list[str] | tuple[str, ...], frame_id: str = "") -> None:
        self.layout = JointStateLayout.of(names, frame_id)

    def encode(self, stamp_ns: int, values: Any) -> bytes:
        return self.layout.pack(stamp_ns, values)


# -- decoding ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class JointState:
    """A decoded ``sensor_msgs/msg/JointState``."""

    stamp_ns: int
    frame_id: str
    name: list[str]
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray


class _Reader:
    def __init__(self, data: bytes | memoryview, what: str) -> None:
        if bytes(data[:2]) != ENCAPSULATION[:2]:
            raise BridgeError(
                f"{what}: expected little-endian CDR (encapsulation 00 01), got {bytes(data[:2]).hex()}; "
                "only CDR_LE payloads are supported"
            )
        self.data = memoryview(data)[4:]
        self.pos = 0
        self.what = what

    def take(self, fmt: str, align: int) -> tuple[Any, ...]:
        self.pos += -self.pos % align
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise BridgeError(f"{self.what}: payload ends at byte {len(self.data)}, a field needs more")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values

    def string(self) -> str:
        (length,) = self.take("<I", 4)
        raw = bytes(self.take(f"{length}s", 1)[0])
        return raw[:-1].decode("utf-8", "replace") if length else ""

    def doubles(self) -> FloatArray:
        (count,) = self.take("<I", 4)
        if not count:
            return np.zeros(0)
        return np.array(self.take(f"<{count}d", 8), dtype=np.float64)


def decode_joint_state(data: bytes | memoryview) -> JointState:
    reader = _Reader(data, JOINT_STATE)
    sec, nanosec = reader.take("<iI", 4)
    frame_id = reader.string()
    (count,) = reader.take("<I", 4)
    names = [reader.string() for _ in range(count)]
    position, velocity, effort = reader.doubles(), reader.doubles(), reader.doubles()
    return JointState(sec * 1_000_000_000 + nanosec, frame_id, names, position, velocity, effort)


def decode_float64(data: bytes | memoryview) -> float:
    return float(_Reader(data, FLOAT64).take("<d", 8)[0])


def decode_string(data: bytes | memoryview) -> str:
    return _Reader(data, STRING).string()


def decode_joint_states(payloads: list[bytes]) -> tuple[list[str], npt.NDArray[np.int64], FloatArray]:
    """Names, stamps (ns) and an ``(n, len(names))`` position array of JointStates of one channel.

    Messages written with one fixed layout (as fmu-bridge writes them) decode in one numpy
    call; others (names that change, velocities, big-endian) one by one, in which case the
    names of the first message are used and positions missing from later ones are NaN.
    """
    if not payloads:
        return [], np.zeros(0, dtype=np.int64), np.zeros((0, 0))
    first = decode_joint_state(payloads[0])
    layout = JointStateLayout.of(first.name, first.frame_id)
    fixed = all(len(p) == layout.size for p in payloads)
    if fixed:
        dtype = np.dtype(
            {
                "names": ["sec", "nsec", "head", "values"],
                "formats": ["<i4", "<u4", f"V{len(layout.head)}", ("<f8", (len(first.name),))],
                "offsets": [4, 8, 12, 12 + len(layout.head)],
                "itemsize": layout.size,
            }
        )
        records = np.frombuffer(b"".join(payloads), dtype=dtype)
        if bool(np.all(records["head"] == np.void(layout.head))) and first.velocity.size == 0:
            stamps = records["sec"].astype(np.int64) * 1_000_000_000 + records["nsec"]
            return first.name, stamps, records["values"].reshape(len(payloads), -1).astype(np.float64)
    messages = [decode_joint_state(p) for p in payloads]
    values = np.full((len(messages), len(first.name)), np.nan)
    for row, message in enumerate(messages):
        for col, name in enumerate(first.name):
            if name in message.name and message.name.index(name) < message.position.size:
                values[row, col] = message.position[message.name.index(name)]
    return first.name, np.array([m.stamp_ns for m in messages], dtype=np.int64), values
