"""Liveliness tokens, QoS strings and GIDs, pinned to the rmw_zenoh design document's examples."""

from __future__ import annotations

import pytest

from bridge.errors import ConfigError, TransportError
from bridge.net.ros2.qos import QoS
from bridge.net.ros2.tokens import Endpoint, EntityKind, Token, gid

STRING = "std_msgs::msg::dds_::String_"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS = "example_interfaces::srv::dds_::AddTwoInts_"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"

# Verbatim from docs/design.md (rmw_zenoh, the zenoh-cpp version that matches Jazzy >= 0.2.4).
DESIGN_TOKENS = {
    "listener node": "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener",
    "listener subscription": (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"{STRING}/{STRING_HASH}/::,10:,:,:,,"
    ),
    "talker publisher": (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"{STRING}/{STRING_HASH}/::,7:,:,:,,"
    ),
    "service server": (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/"
        f"{ADD_TWO_INTS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,"
    ),
    "service client": (
        "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/%add_two_ints/"
        f"{ADD_TWO_INTS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,"
    ),
}


def _token(zid: str, eid: int, kind: EntityKind, node: str, endpoint: Endpoint | None) -> Token:
    return Token(2, zid, 0, eid, kind, "/", node, enclave="/", endpoint=endpoint)


def test_node_token_matches_design_document() -> None:
    token = _token("aac3178e146ba6f1fc6e6a4085e77f21", 0, EntityKind.NODE, "listener", None)
    assert token.key == DESIGN_TOKENS["listener node"]


CHATTER = Endpoint("/chatter", STRING, STRING_HASH, QoS(depth=10))
ADD_TWO_INTS_SERVICE = Endpoint("/add_two_ints", ADD_TWO_INTS, ADD_TWO_INTS_HASH, QoS(depth=10))


@pytest.mark.parametrize(
    ("example", "zid", "kind", "node", "endpoint"),
    [
        ("listener subscription", "aac3178e146ba6f1fc6e6a4085e77f21", EntityKind.SUBSCRIPTION, "listener",
         CHATTER),
        ("talker publisher", "8b20917502ee955ac4476e0266340d5c", EntityKind.PUBLISHER, "talker",
         Endpoint("/chatter", STRING, STRING_HASH, QoS(depth=7))),
        ("service server", "f9980ee0495eaafb3e38f0d19e2eae12", EntityKind.SERVICE, "add_two_ints_server",
         ADD_TWO_INTS_SERVICE),
        ("service client", "e1dc8d1b45ae8717fce78689cc655685", EntityKind.CLIENT, "add_two_ints_client",
         ADD_TWO_INTS_SERVICE),
    ],
)  # fmt: skip
def test_entity_tokens_match_design_document(
    example: str, zid: str, kind: EntityKind, node: str, endpoint: Endpoint
) -> None:
    assert _token(zid, 10, kind, node, endpoint).key == DESIGN_TOKENS[example]


@pytest.mark.parametrize("example", sorted(DESIGN_TOKENS))
def test_design_tokens_parse_and_rebuild_identically(example: str) -> None:
    key = DESIGN_TOKENS[example]
    token = Token.parse(key)
    assert token.key == key
    assert token.domain_id == 2 and token.namespace == "/" and token.enclave == "/"


def test_parsed_token_demangles_names_and_types() -> None:
    token = Token.parse(DESIGN_TOKENS["talker publisher"])
    assert token.kind == EntityKind.PUBLISHER
    assert token.node_name == "talker" and token.entity_id == 10
    assert token.endpoint is not None
    assert token.endpoint.name == "/chatter"
    assert token.endpoint.type_name == "std_msgs/msg/String"
    assert token.endpoint.qos.depth == 7


def test_namespace_and_topic_are_mangled_with_percent() -> None:
    endpoint = Endpoint("/robot1/joint_states", "sensor_msgs::msg::dds_::JointState_", "RIHS01_h", QoS())
    token = Token(0, "ab12", 3, 5, EntityKind.PUBLISHER, "/robot1", "sim", enclave="/", endpoint=endpoint)
    assert token.key == (
        "@ros2_lv/0/ab12/3/5/MP/%/%robot1/sim/%robot1%joint_states/"
        "sensor_msgs::msg::dds_::JointState_/RIHS01_h/::,10:,:,:,,"
    )
    assert Token.parse(token.key) == token


def test_empty_namespace_and_enclave_are_written_as_percent() -> None:
    token = Token(0, "ab12", 0, 0, EntityKind.NODE, "", "sim", enclave="")
    assert token.key == "@ros2_lv/0/ab12/0/0/NN/%/%/sim"


@pytest.mark.parametrize(
    "bad",
    [
        "fmu_bridge/x/alive",
        "@ros2_lv/0/zid/0/0/XX/%/%/n",
        "@ros2_lv/0/zid/0/0/NN/%/%",
        "@ros2_lv/0/zid//0/NN/%/%/n",
        "@ros2_lv/0/zid/0/1/MP/%/%/n/%t/T_/RIHS01_h",
        "@ros2_lv/0/zid/0/1/MP/%/%/n/%t/T_/RIHS01_h/4::,:,:,:,,",
    ],
)
def test_foreign_or_malformed_tokens_raise_transport_error(bad: str) -> None:
    with pytest.raises(TransportError):
        Token.parse(bad)


def test_node_token_with_endpoint_is_refused() -> None:
    endpoint = Endpoint("/x", STRING, STRING_HASH, QoS())
    with pytest.raises(ConfigError, match="must not"):
        _ = Token(0, "z", 0, 0, EntityKind.NODE, "/", "n", endpoint=endpoint).key


# GID = XXH3-128 of the token string, low64 LE then high64 LE (research note, derived with xxhash 4.1.0).
@pytest.mark.parametrize(
    ("key", "expected"),
    [
        (DESIGN_TOKENS["listener node"], "49877999dacb858702d11ac823785912"),
        (DESIGN_TOKENS["talker publisher"], "ac170f31eadcd9ff0cd86d7a17907d1c"),
    ],
)
def test_gid_is_xxh3_128_of_the_token(key: str, expected: str) -> None:
    assert gid(key).hex() == expected
    assert Token.parse(key).gid.hex() == expected
