"""ROS 2 quality of service profiles and rmw_zenoh's compact QoS string for liveliness tokens.

The string (rmw_zenoh ``qos_to_keyexpr``) is
``<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease s>,<ns>``
where every field that equals rmw_zenoh's default is left empty. The defaults (Jazzy >= 0.2.3) are
RELIABLE, VOLATILE, KEEP_LAST, depth 42, infinite durations and AUTOMATIC liveliness, so a depth-10
profile reads ``::,10:,:,:,,``. Enum values are those of ``rmw/types.h``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum

from bridge.errors import ConfigError

NS_PER_S = 1_000_000_000
RMW_DEFAULT_DEPTH = 42
# RMW_DURATION_INFINITE is {9223372036 s, 854775807 ns}: INT64_MAX nanoseconds.
DURATION_INFINITE_NS = 9_223_372_036_854_775_807


class Reliability(IntEnum):
    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2


class Liveliness(IntEnum):
    SYSTEM_DEFAULT = 0
    AUTOMATIC = 1
    MANUAL_BY_TOPIC = 3


@dataclass(frozen=True)
class QoS:
    """A ROS 2 QoS profile. Durations are in ns; ``None`` (or 0) means unspecified, i.e. infinite.

    The default is rclcpp's and rclpy's usual one: RELIABLE, VOLATILE, KEEP_LAST with depth 10.
    """

    depth: int = 10
    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST
    deadline_ns: int | None = None
    lifespan_ns: int | None = None
    liveliness: Liveliness = Liveliness.AUTOMATIC
    liveliness_lease_ns: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise ConfigError(f"QoS depth must be an integer >= 0, got {self.depth!r}")
        for name in ("deadline_ns", "lifespan_ns", "liveliness_lease_ns"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 0):
                raise ConfigError(f"QoS {name} must be None or an integer number of ns >= 0, got {value!r}")

    @property
    def transient_local(self) -> bool:
        return self.durability == Durability.TRANSIENT_LOCAL

    @property
    def reliable(self) -> bool:
        return self.reliability != Reliability.BEST_EFFORT

    def adapted(self) -> QoS:
        """The profile as rmw_zenoh stores it: system defaults and a zero depth become its defaults."""
        return replace(
            self,
            reliability=self.reliability or Reliability.RELIABLE,
            durability=self.durability or Durability.VOLATILE,
            history=self.history or History.KEEP_LAST,
            depth=self.depth or RMW_DEFAULT_DEPTH,
            liveliness=self.liveliness or Liveliness.AUTOMATIC,
        )

    def to_keyexpr(self) -> str:
        """The compact string rmw_zenoh puts at the end of a publisher's or subscription's token."""
        qos = self.adapted()
        rel = _unless(qos.reliability, Reliability.RELIABLE)
        dur = _unless(qos.durability, Durability.VOLATILE)
        hist = _unless(qos.history, History.KEEP_LAST)
        depth = _unless(qos.depth, RMW_DEFAULT_DEPTH)
        live = _unless(qos.liveliness, Liveliness.AUTOMATIC)
        return (
            f"{rel}:{dur}:{hist},{depth}:{_duration(qos.deadline_ns)}:{_duration(qos.lifespan_ns)}:"
            f"{live},{_duration(qos.liveliness_lease_ns)}"
        )

    @classmethod
    def from_keyexpr(cls, text: str) -> QoS:
        """Parse a token's QoS string; empty fields take rmw_zenoh's defaults (depth 42 included)."""
        try:
            rel, dur, hist_depth, deadline, lifespan, live_lease = text.split(":")
            hist, depth = hist_depth.split(",")
            live, lease_s, lease_ns = live_lease.split(",")
            return cls(
                depth=int(depth) if depth else RMW_DEFAULT_DEPTH,
                reliability=Reliability(int(rel)) if rel else Reliability.RELIABLE,
                durability=Durability(int(dur)) if dur else Durability.VOLATILE,
                history=History(int(hist)) if hist else History.KEEP_LAST,
                deadline_ns=_parse_duration(deadline),
                lifespan_ns=_parse_duration(lifespan),
                liveliness=Liveliness(int(live)) if live else Liveliness.AUTOMATIC,
                liveliness_lease_ns=_parse_duration(f"{lease_s},{lease_ns}"),
            )
        except ValueError as exc:
            raise ConfigError(
                f"QoS string {text!r} is not rmw_zenoh's format "
                f"'rel:dur:hist,depth:dl_s,dl_ns:ls_s,ls_ns:live,lease_s,lease_ns' ({exc})"
            ) from None


def _unless(value: int, default: int) -> str:
    return "" if value == default else str(int(value))


def _duration(value_ns: int | None) -> str:
    if not value_ns or value_ns >= DURATION_INFINITE_NS:
        return ","
    return f"{value_ns // NS_PER_S},{value_ns % NS_PER_S}"


def _parse_duration(text: str) -> int | None:
    sec, nsec = text.split(",")
    if not sec and not nsec:
        return None
    return int(sec or 0) * NS_PER_S + int(nsec or 0)


DEFAULT = QoS()
"""RELIABLE, VOLATILE, KEEP_LAST 10: rclpy's usual choice and what ``ros2 topic pub`` uses."""
SENSOR_DATA = QoS(depth=5, reliability=Reliability.BEST_EFFORT)
"""rmw's sensor data profile: BEST_EFFORT, KEEP_LAST 5."""
SERVICES_DEFAULT = QoS(depth=10)
"""rmw's services profile (the SS/SC tokens of rclcpp carry ``::,10:,:,:,,``)."""
LATCHED = QoS(depth=1, durability=Durability.TRANSIENT_LOCAL)
"""TRANSIENT_LOCAL, KEEP_LAST 1: late subscribers get the last sample (``/robot_description`` style)."""
