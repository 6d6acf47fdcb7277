"""CDR, the ROS 2 wire encoding: every payload fmu-bridge writes or reads, in one module.

Payloads are little-endian CDR with the 4-byte encapsulation header ``00 01 00 00`` (what
rmw_zenoh's Fast-CDR sends and rosbags writes); alignment counts from the end of that header.
Two paths:

- **rosbags** (Jazzy typestore) for the generic case: any message or service type
  (:func:`serialize`, :func:`deserialize`, :func:`encode`), and a JointState with any fields
  (:func:`encode_joint_state`). Hand-written code was only 1.3-1.6x faster there.
- **fixed layouts** for the few standard messages sent every step: a JointState with fixed names
  (:class:`JointStateLayout`: a constant head and tail around ``sec, nanosec`` and ``n``
  float64, packed one at a time or, by ``bridge.recording.block``, thousands at once),
  ``std_msgs/msg/Float64``, ``std_msgs/msg/String`` and ``rosgraph_msgs/msg/Clock``. Their
  layouts are taken from rosbags' own serialization, so both paths give the same bytes.

Decoding the standard messages (:func:`decode_joint_state`, :func:`decode_joint_states`, ...) is
hand-written and bounded: a recording or a peer may send anything, and every length is checked
against what is left of the payload before it is used.
"""

from __future__ import annotations

import struct
import threading
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError, TransportError
from bridge.net.ros2.typehash import SERVICE_DEFINITIONS, jazzy_typestore, service_fields

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, no options
CDR_HEADERS = (b"\x00\x00", b"\x00\x01")  # CDR_BE, CDR_LE; two option bytes follow
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
STRING = "std_msgs/msg/String"
FloatArray = npt.NDArray[np.float64]
_LOCK = threading.Lock()
_CLOCK = struct.Struct("<4siI")  # CDR header, builtin_interfaces/Time (int32 sec, uint32 nanosec)


# -- the generic path: rosbags -------------------------------------------------------------------
@cache
def typestore() -> Any:
    """The Jazzy typestore with the request and response types of ``SERVICE_DEFINITIONS`` added."""
    with _LOCK:
        store = jazzy_typestore()
        for srv_type in SERVICE_DEFINITIONS:
            store.register(service_fields(srv_type))
        return store


def message_class(type_name: str) -> Any:
    """The rosbags dataclass of a type, e.g. ``message_class('std_msgs/msg/Float64')(data=1.5)``."""
    store = typestore()
    try:
        return store.types[type_name]
    except KeyError:
        raise ConfigError(
            f"ROS type {type_name!r} is not in the Jazzy typestore; services are used as "
            "'pkg/srv/X_Request' and 'pkg/srv/X_Response'"
        ) from None


def serialize(message: Any, type_name: str) -> bytes:
    """CDR little-endian with the encapsulation header, exactly what rmw_zenoh publishes."""
    try:
        return bytes(typestore().serialize_cdr(message, type_name, little_endian=True))
    except Exception as exc:
        raise ConfigError(f"cannot serialize {message!r} as {type_name}: {exc}") from exc


def deserialize(data: bytes, type_name: str) -> Any:
    """Decode a CDR payload; a payload that does not fit the type raises ``TransportError``."""
    check_cdr(data)
    try:
        return typestore().deserialize_cdr(data, type_name)
    except Exception as exc:
        raise TransportError(f"cannot decode a {len(data)}-byte CDR payload as {type_name}: {exc}") from exc


def encode(type_name: str, **fields: Any) -> bytes:
    """Build and serialize a message in one call: ``encode('std_msgs/msg/Float64', data=1.5)``."""
    try:
        message = message_class(type_name)(**fields)
    except TypeError as exc:
        raise ConfigError(f"fields {sorted(fields)} do not fit {type_name}: {exc}") from None
    return serialize(message, type_name)


def check_cdr(data: bytes) -> bytes:
    """Raise ``TransportError`` unless ``data`` starts with a plain CDR encapsulation header."""
    if len(data) < 4 or data[:2] not in CDR_HEADERS:
        raise TransportError(
            f"payload {data[:8].hex(' ')!r} ({len(data)} bytes) does not start with a CDR encapsulation "
            "header (00 01 00 00 little-endian, 00 00 00 00 big-endian); serialize with "
            "bridge.net.ros2.cdr.serialize or rosbags' serialize_cdr"
        )
    return data


@cache
def schema_text(msgtype: str) -> str:
    """The ``ros2msg`` schema of a standard ROS 2 Jazzy type, with its dependencies appended."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return str(text)


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` fields (sec, nanosec) of a time in ns (sec is floored)."""
    return divmod(stamp_ns, 1_000_000_000)


def encode_joint_state(
    stamp_ns: int,
    names: list[str] | tuple[str, ...],
    position: Any,
    *,
    velocity: Any = (),
    effort: Any = (),
    frame_id: str = "",
) -> bytes:
    """A ``sensor_msgs/msg/JointState`` payload (general form, by rosbags: any names and arrays)."""
    sec, nanosec = split_ns(int(stamp_ns))
    types = typestore().types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec, nanosec), frame_id=frame_id
    )
    arrays = [np.ascontiguousarray(v, dtype=np.float64).ravel() for v in (position, velocity, effort)]
    return serialize(types[JOINT_STATE](header, [str(n) for n in names], *arrays), JOINT_STATE)


# -- fixed layouts -------------------------------------------------------------------------------
def encode_float64(value: float) -> bytes:
    """A ``std_msgs/msg/Float64`` payload."""
    return ENCAPSULATION + struct.pack("<d", value)


def encode_string(text: str) -> bytes:
    """A ``std_msgs/msg/String`` payload."""
    data = text.encode("utf-8") + b"\x00"
    return ENCAPSULATION + struct.pack("<I", len(data)) + data


def encode_clock(sim_time_ns: int) -> bytes:
    """A ``rosgraph_msgs/msg/Clock`` payload."""
    return _CLOCK.pack(ENCAPSULATION, *split_ns(int(sim_time_ns)))


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
        """The layout rosbags serializes: its bytes around the stamp and the positions."""
        full = encode_joint_state(0, names, np.zeros(len(names)), frame_id=frame_id)
        tail = struct.pack("<II", 0, 0)  # empty velocity and effort
        head = full[len(ENCAPSULATION) + 8 : len(full) - 8 * len(names) - len(tail)]
        return cls(tuple(names), head, tail)

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


def decode_clock(data: bytes | memoryview) -> int:
    """The time of a ``rosgraph_msgs/msg/Clock`` payload, in ns."""
    raw = bytes(data)
    if len(raw) < 12:
        raise ValueError(f"a Clock message has 12 bytes, got {len(raw)}")
    sec, nanosec = struct.unpack_from("<iI", raw, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


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
