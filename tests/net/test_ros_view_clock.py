"""``fmu-bridge node --follow-clock`` over the rmw_zenoh view: the FMU stepped by another simulator's
/clock, published by a peer written from the rmw_zenoh design document alone (plain zenoh-python,
literal key expressions, struct for the attachment, rosbags for CDR) at 1x (ticks finer than the
step), 10x (coarser) and with a jump back. The same schedule as tests/ros/test_follow_clock.py."""

from __future__ import annotations

import random
import struct
import threading
import time
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, node_process, wait_for

pytestmark = pytest.mark.integration
JAZZY = get_typestore(Stores.ROS2_JAZZY)
CARTPOLE = example_experiment("cartpole_balance")
STEP_NS = 20_000_000  # the experiment's sampling time
JOINT_STATE = "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"  # noqa: E501
CLOCK = (
    "rosgraph_msgs::msg::dds_::Clock_/RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564"
)


def clock_message(stamp_ns: int) -> bytes:
    types = JAZZY.types
    stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    message = types["rosgraph_msgs/msg/Clock"](clock=stamp)
    return bytes(JAZZY.serialize_cdr(message, "rosgraph_msgs/msg/Clock"))


def stamp_of(payload: bytes) -> int:
    header = JAZZY.deserialize_cdr(payload, "sensor_msgs/msg/JointState").header
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)


class ClockPeer:
    """Publishes /clock and collects the follower's output stamps, on the test's own session."""

    def __init__(self, session: Any, domain: int, node: str) -> None:
        self.session, self.domain, self.seq = session, domain, 0
        self.gid = random.randbytes(16)
        self.stamps: list[int] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(f"{domain}/{node}/outputs/{JOINT_STATE}", self._on_output)

    def _on_output(self, sample: Any) -> None:
        with self._lock:
            self.stamps.append(stamp_of(sample.payload.to_bytes()))

    def received(self) -> list[int]:
        with self._lock:
            return list(self.stamps)

    def tick(self, clock_ns: int) -> None:
        self.seq += 1  # design.md attachment: sequence number, source timestamp, GID length and GID
        attachment = struct.pack("<qqB16s", self.seq, time.time_ns(), 16, self.gid)
        self.session.put(f"{self.domain}/clock/{CLOCK}", clock_message(clock_ns), attachment=attachment)

    def tokens(self) -> set[str]:
        replies = self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=2.0)
        return {str(r.ok.key_expr) for r in replies if r.ok}

    def close(self) -> None:
        self._sub.undeclare()


def test_fmu_time_follows_a_zenoh_clock_at_1x_10x_and_back(loopback: Loopback) -> None:
    domain = random.SystemRandom().randint(1, 100)
    args = ("--ros-backend", "zenoh", "--ros-domain", str(domain), "--follow-clock")
    with node_process(CARTPOLE, "follower", loopback, *args):
        peer = ClockPeer(loopback.session, domain, "follower")
        try:
            clock_tokens = wait_for(
                lambda: {t for t in peer.tokens() if "/%clock/" in t},
                10.0,
                "the node's /clock subscription token",
            )
            # it follows the clock (a subscription), it does not publish one
            assert all("/MS/" in t for t in clock_tokens), clock_tokens
            # 1x: 10 ms ticks (finer than the 20 ms step) for 0.4 s; 10x: 100 ms ticks (five steps
            # each) for 1 s; then back to 0.25 s (a reset of the other simulator), and on at 10x
            ticks = [10_000_000 * i for i in range(41)]
            ticks += [ticks[-1] + 100_000_000 * i for i in range(1, 11)]
            ticks += [250_000_000 + 100_000_000 * i for i in range(6)]
            seen = origin = previous_steps = 0
            for k, clock in enumerate(ticks):
                restart = k == 0 or clock < ticks[k - 1]
                if restart:
                    origin, previous_steps = clock, 0  # the FMU starts again, lined up with the clock
                expected_steps = (clock - origin) // STEP_NS
                peer.tick(clock)
                # each tick: step 0 at a (re)start, then one sample per step due; none early, none late
                seen += (1 if restart else 0) + expected_steps - previous_steps
                stamps = wait_for(
                    lambda n=seen: len(peer.received()) >= n and peer.received(), 30.0, f"{seen} samples"
                )
                fmu = stamps[-1]  # the FMU's time on the clock's scale
                assert len(stamps) == seen, (k, clock, stamps[-10:])
                assert clock - STEP_NS < fmu <= clock, (k, clock, fmu)
                assert fmu == origin + expected_steps * STEP_NS
                previous_steps = expected_steps
            time.sleep(0.3)  # a step ahead of the clock would arrive by now
            stamps = peer.received()
            assert len(stamps) == seen, stamps[seen:]
            assert stamps[0] == 0 and stamps.count(250_000_000) == 1  # one restart, at the jump back
        finally:
            peer.close()
