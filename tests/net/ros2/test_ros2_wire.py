"""End to end on loopback: our RosNode against a peer written from the rmw_zenoh design document alone.

The peer side uses plain zenoh-python, literal key expressions and token strings, ``struct`` for
the attachment and rosbags or mcap_ros2 for CDR: nothing from ``bridge.net.ros2``.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import xxhash
import zenoh
from mcap_ros2._dynamic import generate_dynamic
from ros2_fixtures import eventually_fixture, peer_session_fixture, ros_session_fixture  # noqa: F401
from rosbags.typesys import Stores, get_typestore

from bridge.net.ros2 import RosContext, graph, interfaces

pytestmark = pytest.mark.integration

JOINT_STATE = "sensor_msgs::msg::dds_::JointState_"
JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
TRIGGER = "std_srvs::srv::dds_::Trigger_"
TRIGGER_HASH = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
JOINT_STATES_KEY = f"0/joint_states/{JOINT_STATE}/{JOINT_STATE_HASH}"
RESET_KEY = f"0/sim/reset/{TRIGGER}/{TRIGGER_HASH}"
TRIGGER_REQUEST = bytes.fromhex("0001000000")
JAZZY = get_typestore(Stores.ROS2_JAZZY)
Eventually = Callable[..., Any]


def attachment(seq: int, gid: bytes, stamp_ns: int | None = None) -> bytes:
    """design.md: int64 LE sequence number, int64 LE timestamp, one byte 16, 16-byte GID."""
    return struct.pack("<qqB16s", seq, time.time_ns() if stamp_ns is None else stamp_ns, 16, gid)


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    assert len(raw) == 33 and raw[16] == 16
    seq, stamp = struct.unpack_from("<qq", raw)
    return seq, stamp, raw[17:33]


def xxh3_gid(token: str) -> bytes:
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")


def live_tokens(session: Any) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**", timeout=2.0) if r.ok}


def joint_state(names: list[str], positions: list[float], stamp_ns: int) -> bytes:
    """JointState CDR straight from rosbags (the peer's own serializer)."""
    types = JAZZY.types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="",
    )
    empty = np.array([], dtype=np.float64)
    message = types["sensor_msgs/msg/JointState"](
        header=header,
        name=names,
        position=np.array(positions, dtype=np.float64),
        velocity=empty,
        effort=empty,
    )
    return bytes(JAZZY.serialize_cdr(message, "sensor_msgs/msg/JointState"))


def test_independent_subscriber_receives_joint_states(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    received: list[tuple[bytes, bytes]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        assert sample.attachment is not None
        with lock:
            received.append((sample.payload.to_bytes(), sample.attachment.to_bytes()))

    subscriber = peer_session.declare_subscriber(JOINT_STATES_KEY, on_sample)
    with RosContext(ros_session, domain_id=0) as ros:
        publisher = ros.create_node("sim").create_publisher("joint_states", "sensor_msgs/msg/JointState")
        assert publisher.key == JOINT_STATES_KEY
        before_ns = time.time_ns()
        step, deadline = 0, time.monotonic() + 30
        while not received:  # probe until the subscription has propagated, then send a known series
            step += 1
            publisher.publish(joint_state(["x", "theta"], [0.1 * step, -step], stamp_ns=step * 20_000_000))
            time.sleep(0.05)
            assert time.monotonic() < deadline, "the subscriber never received a sample"
        for _ in range(5):
            step += 1
            publisher.publish(joint_state(["x", "theta"], [0.1 * step, -step], stamp_ns=step * 20_000_000))
        last = step
        eventually(lambda: received and parse_attachment(received[-1][1])[0] == last, what="the last sample")
        after_ns = time.time_ns()
        mp_tokens = eventually(
            lambda: [t for t in live_tokens(peer_session) if "/MP/" in t], what="the MP token"
        )
    subscriber.undeclare()

    sequences = []
    for payload, raw in received:
        seq, stamp_ns, gid = parse_attachment(raw)
        sequences.append(seq)
        assert before_ns <= stamp_ns <= after_ns
        assert gid == xxh3_gid(mp_tokens[0])
        message = JAZZY.deserialize_cdr(payload, "sensor_msgs/msg/JointState")
        assert message.name == ["x", "theta"]
        assert message.position.tolist() == pytest.approx([0.1 * seq, -seq])
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == seq * 20_000_000
        assert message.velocity.size == 0 and message.effort.size == 0
    assert sequences == list(range(sequences[0], step + 1))  # from 1, +1 per message, none lost


def test_liveliness_tokens_describe_node_and_endpoints(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    zid = str(ros_session.zid())
    ros = RosContext(ros_session, domain_id=0)
    node = ros.create_node("sim")
    node.create_publisher("joint_states", "sensor_msgs/msg/JointState")
    node.create_subscription("actions", "sensor_msgs/msg/JointState", lambda payload, info: None)
    node.create_service("~/reset", "std_srvs/srv/Trigger", lambda request: request)
    node.create_client("/other/reset", "std_srvs/srv/Trigger")
    expected = {
        f"@ros2_lv/0/{zid}/0/0/NN/%/%/sim",
        f"@ros2_lv/0/{zid}/0/1/MP/%/%/sim/%joint_states/{JOINT_STATE}/{JOINT_STATE_HASH}/::,10:,:,:,,",
        f"@ros2_lv/0/{zid}/0/2/MS/%/%/sim/%actions/{JOINT_STATE}/{JOINT_STATE_HASH}/::,10:,:,:,,",
        f"@ros2_lv/0/{zid}/0/3/SS/%/%/sim/%sim%reset/{TRIGGER}/{TRIGGER_HASH}/::,10:,:,:,,",
        f"@ros2_lv/0/{zid}/0/4/SC/%/%/sim/%other%reset/{TRIGGER}/{TRIGGER_HASH}/::,10:,:,:,,",
    }
    eventually(lambda: live_tokens(peer_session) == expected, what="the five tokens")
    found: list[Any] = []

    def discovered() -> bool:  # one liveliness query may time out on a loaded machine: ask again
        found[:] = graph.discover(peer_session, 0)
        return len(found) == len(expected)

    eventually(discovered, what="graph.discover to answer with the five tokens")
    tokens = list(found)
    assert graph.node_names(tokens) == ["/sim"]
    assert graph.topic_names_and_types(tokens) == {
        "/joint_states": {"sensor_msgs/msg/JointState"},
        "/actions": {"sensor_msgs/msg/JointState"},
    }
    assert {t.key for t in tokens} == expected  # parsing and rebuilding is lossless
    ros.close()
    eventually(lambda: not live_tokens(peer_session), what="all tokens withdrawn after close()")


def test_trigger_service_answers_a_design_document_query(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    requests: list[bytes] = []

    def handler(request: bytes) -> bytes:
        requests.append(request)
        return interfaces.trigger_response(True, "reset done")

    with RosContext(ros_session, domain_id=0) as ros:
        ros.create_node("sim").create_service("~/reset", "std_srvs/srv/Trigger", handler)
        eventually(lambda: any("/SS/" in t for t in live_tokens(peer_session)), what="the SS token")
        client_gid = bytes(range(100, 116))
        before_ns = time.time_ns()
        replies = list(
            peer_session.get(
                RESET_KEY,
                payload=TRIGGER_REQUEST,
                attachment=attachment(7, client_gid),
                target=zenoh.QueryTarget.ALL_COMPLETE,  # what rmw_zenoh clients use: needs complete=True
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=30.0,
            )
        )
        after_ns = time.time_ns()
    assert len(replies) == 1 and replies[0].ok is not None
    sample = replies[0].ok
    assert str(sample.key_expr) == RESET_KEY
    seq, stamp_ns, gid = parse_attachment(sample.attachment.to_bytes())
    assert (seq, gid) == (7, client_gid)  # the request's sequence number and the client's GID
    assert before_ns <= stamp_ns <= after_ns  # a fresh timestamp
    decoder = generate_dynamic("std_srvs/Trigger_Response", "bool success\nstring message\n")
    response = decoder["std_srvs/Trigger_Response"](sample.payload.to_bytes())
    assert response.success is True and response.message == "reset done"
    assert requests == [TRIGGER_REQUEST]


def test_service_refuses_a_request_without_attachment(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    with RosContext(ros_session, domain_id=0) as ros:
        service = ros.create_node("sim").create_service(
            "~/reset", "std_srvs/srv/Trigger", lambda request: interfaces.trigger_response(True)
        )
        eventually(lambda: any("/SS/" in t for t in live_tokens(peer_session)), what="the SS token")
        replies = list(peer_session.get(RESET_KEY, payload=TRIGGER_REQUEST, timeout=30.0))
        assert len(replies) == 1 and replies[0].err is not None
        assert b"no attachment" in replies[0].err.payload.to_bytes()
        assert service.counters["rejected"] == 1 and service.counters["served"] == 0


def test_subscription_takes_rmw_zenoh_samples_and_drops_malformed_ones(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    got: list[tuple[bytes, int, bytes]] = []
    key = f"0/sim/actions/{JOINT_STATE}/{JOINT_STATE_HASH}"
    gid = bytes(range(16))
    with RosContext(ros_session, domain_id=0) as ros:
        sub = ros.create_node("sim").create_subscription(
            "~/actions",
            "sensor_msgs/msg/JointState",
            lambda payload, info: got.append((payload, info.sequence_number, info.gid)),
        )
        eventually(lambda: any("/MS/" in t for t in live_tokens(peer_session)), what="the MS token")
        good = [joint_state(["force"], [float(i)], stamp_ns=i) for i in range(3)]
        peer_session.put(key, good[0], attachment=attachment(1, gid))
        peer_session.put(key, good[1], attachment=attachment(2, gid))
        peer_session.put(key, good[1])  # no attachment: rmw_zenoh drops it too
        peer_session.put(key, good[1], attachment=attachment(3, gid)[:32])  # truncated
        peer_session.put(key, b"not cdr at all", attachment=attachment(4, gid))
        peer_session.put(key, good[2], attachment=attachment(6, gid))  # seq 4 and 5 never arrived
        eventually(lambda: sub.counters["received"] + sub.counters["dropped"] == 6, what="six samples")
    assert got == [(good[0], 1, gid), (good[1], 2, gid), (good[2], 6, gid)]
    assert sub.counters["dropped"] == 3 and sub.counters["lost"] == 3


def test_client_calls_a_design_document_queryable(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    seen: list[tuple[int, bytes, bytes]] = []

    def on_query(query: zenoh.Query) -> None:
        with query:
            seq, _, gid = parse_attachment(query.attachment.to_bytes())
            seen.append((seq, gid, query.payload.to_bytes()))
            response = bytes.fromhex("0001000001000000030000006f6b00")  # success, "ok"
            query.reply(RESET_KEY, response, attachment=attachment(seq, gid))

    queryable = peer_session.declare_queryable(RESET_KEY, on_query, complete=True)
    server_token = peer_session.liveliness().declare_token(
        f"@ros2_lv/0/{peer_session.zid()}/0/1/SS/%/%/server/%sim%reset/{TRIGGER}/{TRIGGER_HASH}/::,10:,:,:,,"
    )
    with RosContext(ros_session, domain_id=0) as ros:
        client = ros.create_node("caller").create_client("/sim/reset", "std_srvs/srv/Trigger")
        assert client.wait_for_service(timeout_s=30.0)
        first = client.call(TRIGGER_REQUEST, timeout_s=30.0)
        second = client.call_message(
            interfaces.message_class("std_srvs/srv/Trigger_Request")(), timeout_s=30.0
        )
        sc_tokens = eventually(
            lambda: [t for t in live_tokens(peer_session) if "/SC/" in t], what="the SC token"
        )
    server_token.undeclare()
    queryable.undeclare()
    assert first.hex() == "0001000001000000030000006f6b00"
    assert (second.success, second.message) == (True, "ok")
    assert [s for s, _, _ in seen] == [1, 2]  # client sequence numbers start at 1
    assert all(gid == xxh3_gid(sc_tokens[0]) for _, gid, _ in seen)
    assert all(payload == TRIGGER_REQUEST for _, _, payload in seen)
