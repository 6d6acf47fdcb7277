"""Data key expressions and ROS names, pinned to the rmw_zenoh design document (Jazzy)."""

from __future__ import annotations

import pytest

from bridge.errors import ConfigError
from bridge.net.ros2.names import (
    data_key,
    dds_type_name,
    demangle,
    domain_id_from_env,
    mangle,
    name_token,
    normalize_namespace,
    resolve_name,
    ros_type_name,
)

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"


@pytest.mark.parametrize(
    ("domain", "name", "type_name", "type_hash", "expected"),
    [
        # verbatim from docs/design.md, "Topic and Service name mapping to Zenoh key expressions"
        (
            0,
            "/chatter",
            "std_msgs/msg/String",
            STRING_HASH,
            f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}",
        ),
        (
            0,
            "/robot1/chatter",
            "std_msgs/msg/String",
            STRING_HASH,
            f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}",
        ),
        (
            2,
            "/add_two_ints",
            "example_interfaces/srv/AddTwoInts",
            ADD_TWO_INTS_HASH,
            f"2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}",
        ),
    ],
)
def test_data_key_matches_design_document(
    domain: int, name: str, type_name: str, type_hash: str, expected: str
) -> None:
    assert data_key(domain, name, type_name, type_hash) == expected


def test_service_dds_name_is_the_service_not_request_or_response() -> None:
    assert dds_type_name("std_srvs/srv/Trigger") == "std_srvs::srv::dds_::Trigger_"
    assert dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    assert ros_type_name("rosgraph_msgs::msg::dds_::Clock_") == "rosgraph_msgs/msg/Clock"


@pytest.mark.parametrize(
    "bad", ["JointState", "sensor_msgs/JointState", "pkg/action/X", "pkg/msg/", "a/msg/B/C"]
)
def test_malformed_type_names_are_rejected_with_the_expected_form(bad: str) -> None:
    with pytest.raises(ConfigError, match="package/msg/Name"):
        dds_type_name(bad)


@pytest.mark.parametrize(
    ("name", "namespace", "expected"),
    [
        ("chatter", "/", "/chatter"),
        ("chatter", "", "/chatter"),
        ("chatter", "/robot1", "/robot1/chatter"),
        ("chatter", "robot1", "/robot1/chatter"),
        ("/clock", "/robot1", "/clock"),
        ("~/reset", "/robot1", "/robot1/sim/reset"),
        ("~", "/", "/sim"),
        ("a/b", "/ns/x", "/ns/x/a/b"),
    ],
)
def test_names_resolve_as_rcl_expands_them(name: str, namespace: str, expected: str) -> None:
    assert resolve_name(name, namespace, "sim") == expected


@pytest.mark.parametrize("bad", ["", "/", "a//b", "a/", "1abc", "a-b", "{node}/x", "a b"])
def test_invalid_topic_names_raise_config_error(bad: str) -> None:
    with pytest.raises(ConfigError, match="is invalid"):
        resolve_name(bad, "/", "sim")


def test_namespaces_normalise_to_a_leading_slash_and_reject_bad_tokens() -> None:
    assert normalize_namespace("") == "/"
    assert normalize_namespace("/a/b") == "/a/b"
    with pytest.raises(ConfigError, match="namespace"):
        normalize_namespace("/a/")


def test_mangling_replaces_every_slash() -> None:
    assert mangle("/robot1/chatter") == "%robot1%chatter"
    assert mangle("/") == "%"
    assert demangle("%robot1%chatter") == "/robot1/chatter"


def test_data_key_keeps_inner_slashes_and_drops_only_the_leading_one() -> None:
    key = data_key(7, "/a/b/c", "std_msgs/msg/Float64", "RIHS01_x")
    assert key == "7/a/b/c/std_msgs::msg::dds_::Float64_/RIHS01_x"


def test_domain_id_comes_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert domain_id_from_env() == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert domain_id_from_env() == 42
    monkeypatch.setenv("ROS_DOMAIN_ID", "robot")
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='robot'"):
        domain_id_from_env()
    with pytest.raises(ConfigError, match="domain id"):
        data_key(-1, "/x", "std_msgs/msg/Float64", "RIHS01_x")


@pytest.mark.parametrize(
    ("label", "expected"),
    [("x_dot", "x_dot"), ("body.position", "body_position"), ("der(x)", "der_x_"), ("3d", "_3d"), ("", "_")],
)
def test_name_token_turns_variable_names_into_valid_topic_tokens(label: str, expected: str) -> None:
    assert name_token(label) == expected
    assert resolve_name(f"~/{name_token(label)}", "/", "sim") == f"/sim/{expected}"
