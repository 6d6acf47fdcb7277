"""RosContext / RosNode behaviour: ids, our client against our service, errors, latching, closing."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest
import zenoh
from ros2_fixtures import eventually_fixture, peer_session_fixture, ros_session_fixture  # noqa: F401

from bridge.errors import ConfigError, StepTimeout, TransportError
from bridge.net.ros2 import LATCHED, RosContext, graph, interfaces

pytestmark = pytest.mark.integration
Eventually = Callable[..., Any]
TRIGGER = "std_srvs/srv/Trigger"


def test_ids_come_from_one_counter_per_session(ros_session: Any) -> None:
    first, second = RosContext(ros_session, domain_id=3), RosContext(ros_session, domain_id=3)
    a = first.create_node("a")
    pub = a.create_publisher("x", "std_msgs/msg/Float64")
    b = second.create_node("b", namespace="/robot1")
    client = b.create_client("reset", TRIGGER)
    assert (a.node_id, pub.entity_id, b.node_id, client.entity_id) == (0, 1, 2, 3)
    assert b.fully_qualified_name == "/robot1/b" and client.name == "/robot1/reset"
    assert client.key.startswith("3/robot1/reset/std_srvs::srv::dds_::Trigger_/RIHS01_eeff2cd6")
    first.close()
    second.close()


def test_our_client_calls_our_service_across_sessions(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    resets: list[int] = []

    def reset(request: bytes) -> bytes:
        resets.append(len(request))
        return interfaces.trigger_response(True, f"episode {len(resets)}")

    with RosContext(ros_session, domain_id=5) as server_side, RosContext(peer_session, domain_id=5) as caller:
        service = server_side.create_node("sim").create_service("~/reset", TRIGGER, reset)
        client = caller.create_node("agent").create_client("/sim/reset", TRIGGER)
        assert client.wait_for_service(timeout_s=30.0)
        request = interfaces.message_class(f"{TRIGGER}_Request")()
        answers = [client.call_message(request, timeout_s=30.0) for _ in range(3)]
        assert [a.message for a in answers] == ["episode 1", "episode 2", "episode 3"]
        assert all(a.success for a in answers) and resets == [5, 5, 5]
        assert service.counters["served"] == 3
        tokens = eventually(lambda: graph.discover(peer_session, 5), what="the graph")
        assert graph.node_names(tokens) == ["/agent", "/sim"]
        assert graph.service_names_and_types(tokens) == {"/sim/reset": {TRIGGER}}


def test_other_domains_do_not_see_each_other(ros_session: Any, peer_session: Any) -> None:
    with RosContext(ros_session, domain_id=1) as one, RosContext(peer_session, domain_id=2) as two:
        one.create_node("sim").create_service("~/reset", TRIGGER, lambda r: interfaces.trigger_response(True))
        client = two.create_node("agent").create_client("/sim/reset", TRIGGER)
        assert not client.wait_for_service(timeout_s=0.5)
        with pytest.raises(TransportError, match="no server answered /sim/reset"):
            client.call(interfaces.empty_request(TRIGGER), timeout_s=1.0)


def test_slow_service_raises_step_timeout_and_failing_handler_an_error(
    ros_session: Any, peer_session: Any
) -> None:
    def slow(request: bytes) -> bytes:
        time.sleep(1.5)
        return interfaces.trigger_response(True)

    def broken(request: bytes) -> bytes:
        raise RuntimeError("the FMU refused to reset")

    with RosContext(ros_session) as server_side, RosContext(peer_session) as caller:
        node = server_side.create_node("sim")
        node.create_service("slow", TRIGGER, slow)
        node.create_service("broken", TRIGGER, broken)
        agent = caller.create_node("agent")
        slow_client, broken_client = (
            agent.create_client("/slow", TRIGGER),
            agent.create_client("/broken", TRIGGER),
        )
        assert slow_client.wait_for_service(30.0) and broken_client.wait_for_service(30.0)
        with pytest.raises(StepTimeout, match=r"did not answer within 0\.3 s"):
            slow_client.call(interfaces.empty_request(TRIGGER), timeout_s=0.3)
        with pytest.raises(TransportError, match="the FMU refused to reset"):
            broken_client.call(interfaces.empty_request(TRIGGER), timeout_s=30.0)


def test_latched_publisher_serves_a_late_subscriber(
    ros_session: Any, peer_session: Any, eventually: Eventually
) -> None:
    received: list[str] = []
    with RosContext(ros_session) as ros, RosContext(peer_session) as late:
        publisher = ros.create_node("sim").create_publisher("/description", "std_msgs/msg/String", LATCHED)
        for text in ("old", "model: cartpole"):
            publisher.publish(interfaces.encode("std_msgs/msg/String", data=text))
        # no pause: the cache holds the sample once publish returns, and the late subscriber
        # queries every publisher it detects, also one whose declaration reaches it after it starts
        late.create_node("viewer").create_subscription(
            "/description",
            "std_msgs/msg/String",
            lambda payload, info: received.append(
                interfaces.deserialize(payload, "std_msgs/msg/String").data
            ),
            LATCHED,
        )
        eventually(lambda: received, what="the latched sample")
    assert received == ["model: cartpole"]  # depth 1: only the last one


def test_publisher_refuses_non_cdr_and_publishing_after_close(ros_session: Any) -> None:
    with RosContext(ros_session) as ros:
        publisher = ros.create_node("sim").create_publisher("x", "std_msgs/msg/Float64")
        with pytest.raises(TransportError, match="CDR encapsulation header"):
            publisher.publish(b"\x01\x02")
        first = publisher.publish(interfaces.encode("std_msgs/msg/Float64", data=2.0))
        second = publisher.publish(interfaces.encode("std_msgs/msg/Float64", data=3.0))
        assert (first.sequence_number, second.sequence_number) == (1, 2)
        assert first.gid == second.gid == publisher.gid
        publisher.close()
        with pytest.raises(TransportError, match="is closed"):
            publisher.publish(interfaces.encode("std_msgs/msg/Float64", data=4.0))


def test_wrong_kind_of_type_and_closed_node_are_config_and_transport_errors(ros_session: Any) -> None:
    with RosContext(ros_session) as ros:
        node = ros.create_node("sim")
        with pytest.raises(ConfigError, match="needs a 'srv' type"):
            node.create_service("reset", "std_msgs/msg/Float64", lambda r: r)
        with pytest.raises(ConfigError, match="needs a 'msg' type"):
            node.create_publisher("x", TRIGGER)
        with pytest.raises(ConfigError, match="node name 'bad-name'"):
            ros.create_node("bad-name")
        node.close()
        with pytest.raises(TransportError, match="is closed"):
            node.create_publisher("x", "std_msgs/msg/Float64")


def test_context_refuses_a_closed_session(loopback: Any) -> None:
    from bridge.net.transport import ZenohOptions, open_session

    session = open_session(ZenohOptions(connect=(loopback.endpoint,)))
    session.close()
    with pytest.raises(TransportError, match="session is closed"):
        RosContext(session)
    assert isinstance(session, zenoh.Session)
