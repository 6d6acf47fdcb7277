"""Sessions that cannot be forged: hostile peers (a real process and real sessions) on loopback.

A holder proves itself with the session key it learnt from its reset reply; a client believes
only frames signed with that key, from the node's own session; a lease needs a live token."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError, StepError, TransportError
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.handshake import KeyPair, reply_proof
from bridge.net.remote import answer, describe_nodes
from bridge.net.transport import ZenohOptions, open_session
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.serving import experiment_node
from tests.conftest import Loopback, _wait_for_line, node_process, stop_process, wait_for, wait_until

pytestmark = pytest.mark.integration
CARTPOLE = example_experiment("cartpole_continuous")

# A hostile peer: for every action it sees, it answers first with made-up OUTPUTS, ERROR (hung)
# and REJECT frames for that step, and sends two actions of its own for the next step stamped with
# the sender's client id: one with the genuine MAC over other values, one unsigned. It also
# answers reset queries as if it were the node, with a made-up session key.
HOSTILE = """
import os, secrets, struct, sys, threading, zenoh
from bridge.net import protocol as proto
endpoint, prefix, node = sys.argv[1:]
zenoh.init_log_from_env_or("error")
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", '["%s"]' % endpoint)
conf.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(conf)
keys = proto.Keys(prefix, node)
out, act = s.declare_publisher(keys.outputs), s.declare_publisher(keys.actions)
fake_key = secrets.token_bytes(proto.KEY_SIZE)
sent = {"n": 0}

def on_action(sample):
    payload = sample.payload.to_bytes()
    _, kind, flags, episode, step, client = proto.HEADER.unpack_from(payload)
    if kind != proto.ACTION or client == 0:
        return
    out.put(proto.encode_values(proto.OUTPUTS, episode, step, 0, [9.0, 9.0, 9.0, 9.0]))
    out.put(proto.encode_values(proto.OUTPUTS, episode, step, 0, [9.0] * 4, key=fake_key))
    hung = proto.FAILED | proto.HUNG
    out.put(proto.encode_message(proto.ERROR, episode, step, 0, "hostile: hung", flags=hung))
    out.put(proto.encode_message(proto.REJECT, episode, step, client, "conflict: hostile"))
    tampered = bytearray(payload)
    struct.pack_into("<I", tampered, 8, step + 1)  # the next step, under the old MAC
    act.put(bytes(tampered))
    act.put(proto.encode_values(proto.ACTION, episode, step + 1, client, [0.0]))
    sent["n"] += 1

def on_reset(query):
    query.reply(keys.reset, proto.encode_values(proto.OUTPUTS, 1, 0, 0, [9.0] * 4, key=fake_key),
                attachment=fake_key)

entities = [s.declare_subscriber(keys.actions, on_action), s.declare_queryable(keys.reset, on_reset)]
print("hostile ready", flush=True)
sys.stdin.readline()
print("sent", sent["n"], flush=True)
"""


@contextlib.contextmanager
def hostile_peer(net: Loopback, node: str) -> Iterator[subprocess.Popen[str]]:
    cmd = [sys.executable, "-c", HOSTILE, net.endpoint, net.prefix, node]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    try:
        _wait_for_line(process, "hostile ready", timeout_s=60)
        yield process
    finally:
        stop_process(process, timeout_s=10)


def hostile_count(process: subprocess.Popen[str]) -> int:
    assert process.stdin is not None and process.stdout is not None
    process.stdin.write("\n")
    process.stdin.flush()
    line = process.stdout.readline()
    assert line.startswith("sent"), line
    return int(line.split()[1])


def counters(net: Loopback, node: str) -> dict[str, int]:
    return describe_nodes(net.session, [node], prefix=net.prefix, timeout_s=10)[0]["counters"]  # type: ignore[no-any-return]


def test_a_peer_answering_first_or_replaying_the_holders_id_changes_nothing(loopback: Loopback) -> None:
    """Made-up answers are ignored and forged actions refused as not_holder: the trajectory is
    exactly the in-process one, episode after episode."""
    with node_process(CARTPOLE, "victim", loopback), hostile_peer(loopback, "victim") as hostile:
        with (
            RemoteFmuEnv(CARTPOLE, "victim", session=loopback.session, prefix=loopback.prefix) as remote,
            FmuEnv(CARTPOLE) as local,
        ):
            rng = np.random.default_rng(3)
            steps = 0
            for seed in (11, 12):
                np.testing.assert_array_equal(remote.reset(seed=seed)[0], local.reset(seed=seed)[0])
                for _ in range(40):
                    action = rng.uniform(-1, 1, size=1).astype(np.float32)
                    mine, theirs = remote.step(action), local.step(action)
                    np.testing.assert_array_equal(mine[0], theirs[0])
                    assert mine[1:4] == theirs[1:4]
                    steps += 1
                    if mine[2] or mine[3]:
                        break
            seen = hostile_count(hostile)
        assert seen > 0, f"the hostile peer saw none of {steps} actions"
        # the hostile's last forged actions may still be on their way to the node when it says "sent"
        refused = wait_for(
            lambda: (c := counters(loopback, "victim"))["rejected_not_holder"] >= seen and c,
            30,
            f"the node refusing {seen} forged actions",
        )
        assert refused["steps"] == steps and refused["rejected_not_holder"] >= seen


def test_a_session_answering_on_the_reset_key_after_the_node_does_not_hide_the_node(
    loopback: Loopback,
) -> None:
    """Every reply to a reset is read: Zenoh's default consolidation kept one reply per key, so an
    answer from another session that came last hid the node's and the reset said the node died."""
    import zenoh

    keys = proto.Keys(loopback.prefix, "seen")
    asked: list[int] = []

    def late(query: Any) -> None:
        asked.append(1)
        time.sleep(0.3)  # after the node's reply
        query.reply(keys.reset, proto.encode_values(proto.OUTPUTS, 1, 0, 0, [9.0] * 4))

    with node_process(CARTPOLE, "seen", loopback):
        peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
        queryable = peer.declare_queryable(keys.reset, late, complete=True)
        try:
            probe = {"target": zenoh.QueryTarget.ALL, "consolidation": zenoh.ConsolidationMode.NONE}
            wait_until(  # the node refuses the empty request; the late session has been asked
                lambda: (
                    bool(list(loopback.session.get(keys.reset, payload=b"{}", timeout=2.0, **probe)))
                    and bool(asked)
                ),
                30,
                "the late session's queryable reachable",
            )
            with (
                RemoteFmuEnv(CARTPOLE, "seen", session=loopback.session, prefix=loopback.prefix) as remote,
                FmuEnv(CARTPOLE) as local,
            ):
                for seed in (1, 2):
                    np.testing.assert_array_equal(remote.reset(seed=seed)[0], local.reset(seed=seed)[0])
                    zero = np.zeros(1, dtype=np.float32)
                    np.testing.assert_array_equal(remote.step(zero)[0], local.step(zero)[0])
            # the probe and both resets reached it (its callbacks run one at a time, 0.3 s each)
            wait_until(lambda: len(asked) >= 3, 30, "the resets reaching the late session")
        finally:
            queryable.undeclare()
            peer.close()


def test_a_peer_stamping_the_holders_id_gets_not_holder(loopback: Loopback) -> None:
    with (
        node_process(CARTPOLE, "held", loopback),
        RemoteFmuEnv(CARTPOLE, "held", session=loopback.session, prefix=loopback.prefix) as env,
    ):
        env.reset(seed=0)
        env.step(np.zeros(1, dtype=np.float32))
        holder = describe_nodes(loopback.session, ["held"], prefix=loopback.prefix, timeout_s=10)[0]["holder"]
        client = int(holder["client"], 16)
        peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
        try:
            keys = proto.Keys(loopback.prefix, "held")
            answers: list[proto.Frame] = []
            sub = peer.declare_subscriber(
                keys.outputs, lambda s: answers.append(proto.decode(s.payload.to_bytes()))
            )
            forged = proto.encode_values(proto.ACTION, 1, 2, client, [0.0])
            deadline = time.monotonic() + 30  # sent again until the subscription has reached the node
            while not any(a.kind == proto.REJECT for a in answers) and time.monotonic() < deadline:
                peer.put(keys.actions, forged)
                time.sleep(0.05)
            reject = next((a for a in answers if a.kind == proto.REJECT), None)
            assert reject is not None, f"no REJECT within 30 s: {answers[-5:]}"
            assert reject.message.startswith("not_holder") and not reject.flags & proto.SIGNED
            assert reject.sim_time_ns == client
            sub.undeclare()
        finally:
            peer.close()
        with FmuEnv(CARTPOLE) as local:  # the holder's episode goes on, untouched
            local.reset(seed=0)
            local.step(np.zeros(1, dtype=np.float32))
            for _ in range(3):
                zero = np.zeros(1, dtype=np.float32)
                np.testing.assert_array_equal(env.step(zero)[0], local.step(zero)[0])


def refused_resets(peer: Any, keys: proto.Keys, request: dict[str, Any]) -> list[str]:
    replies = peer.get(keys.reset, payload=json.dumps(request), timeout=10)
    return [r.err.payload.to_bytes().decode() for r in replies if r.err is not None]


def test_a_forged_lease_is_refused_and_a_reset_with_the_holders_id_needs_its_session(
    loopback: Loopback,
) -> None:
    with node_process(CARTPOLE, "lease", loopback):
        peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
        keys = proto.Keys(loopback.prefix, "lease")
        try:
            request = {"episode": 1, "client": 0x1234567, "zid": "forged", "inputs": [0.0]}
            refusals = refused_resets(peer, keys, request)
            assert refusals and "no liveliness token" in refusals[0]
            assert describe_nodes(peer, ["lease"], prefix=loopback.prefix, timeout_s=10)[0]["holder"] is None
            with RemoteFmuEnv(CARTPOLE, "lease", session=loopback.session, prefix=loopback.prefix) as env:
                env.reset(seed=0)
                holder = int(
                    describe_nodes(peer, ["lease"], prefix=loopback.prefix, timeout_s=10)[0]["holder"][
                        "client"
                    ],
                    16,
                )
                stolen = {**request, "client": holder, "episode": 2}
                refused = refused_resets(peer, keys, stolen)
                assert refused and "does not prove" in refused[0]
                env.step(np.zeros(1, dtype=np.float32))  # still the holder's episode
                env.reset(seed=1)  # the holder's own next reset proves itself
        finally:
            peer.close()


def test_a_second_node_with_the_same_name_refuses_to_start(loopback: Loopback) -> None:
    with (
        node_process(CARTPOLE, "only", loopback),
        pytest.raises(TransportError, match="a node named 'only' already serves"),
    ):
        experiment_node(CARTPOLE, name="only", options=loopback.options(), prefix=loopback.prefix)  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["other/reset", "*", "**", "w$x", "a b", "..", "n" * 101, "bidi\u202e"])
def test_a_node_name_that_would_widen_its_keys_is_refused_before_anything_starts(
    loopback: Loopback, name: str
) -> None:
    """A node's name is a part of every key it declares: '/', wildcards or '$' would make it
    answer for other nodes' keys."""
    with pytest.raises(BridgeError, match=r"the node name: .*give --name or node\.name a plain one"):
        experiment_node(CARTPOLE, name=name, options=loopback.options(), prefix=loopback.prefix)  # type: ignore[arg-type]


def test_a_malformed_info_reply_is_a_transport_error_naming_the_node(loopback: Loopback) -> None:
    peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
    keys = proto.Keys(loopback.prefix, "liar")
    replies = {"liar": b'{"node": "liar", "input_names": 3}'}
    queryable = peer.declare_queryable(
        keys.info, lambda q: q.reply(keys.info, replies["liar"]), complete=True
    )
    try:
        wait_until(
            lambda: any(r.ok for r in loopback.session.get(keys.info, timeout=2.0)),  # type: ignore[attr-defined]
            30,
            "the liar's info queryable reachable",
        )
        with pytest.raises(TransportError, match=r"node 'liar' sent an info reply .*input_names"):
            RemoteFmuEnv(CARTPOLE, "liar", session=loopback.session, prefix=loopback.prefix, timeout_s=5)
        replies["liar"] = b"[1, 2"
        with pytest.raises(TransportError, match=r"liar.*not JSON"):
            RemoteFmuEnv(CARTPOLE, "liar", session=loopback.session, prefix=loopback.prefix, timeout_s=5)
        listed = describe_nodes(loopback.session, ["liar"], prefix=loopback.prefix)[0]
        assert "not JSON" in listed["error"]
        replies["liar"] = b'{"node": "liar", "counters": "many", "holder": {"client": 7}}'
        listed = describe_nodes(loopback.session, ["liar"], prefix=loopback.prefix)[0]
        assert listed["node"] == "liar" and "info reply that the protocol does not allow" in listed["error"]
        replies["liar"] = b'{"node": "liar", "mode": "replay"}'  # few words, well formed: listed
        listed = describe_nodes(loopback.session, ["liar"], prefix=loopback.prefix)[0]
        assert "error" not in listed and listed["mode"] == "replay" and listed["counters"] == {}
    finally:
        queryable.undeclare()
        peer.close()


def test_the_node_listing_names_an_impostor_instead_of_showing_one_node(loopback: Loopback) -> None:
    """``fmu-bridge nodes`` asks every session that answers on a node's info key: a second one,
    answering after the node with a well-formed info, is reported, not listed as the node."""
    keys = proto.Keys(loopback.prefix, "listed")
    forged = json.dumps({"node": "listed", "mode": "replay"}).encode()
    asked: list[int] = []

    def late(query: Any) -> None:
        asked.append(1)
        time.sleep(0.3)  # after the node's reply
        query.reply(keys.info, forged)

    with node_process(CARTPOLE, "listed", loopback):
        listed = describe_nodes(loopback.session, ["listed"], prefix=loopback.prefix, timeout_s=10)[0]
        assert "error" not in listed and listed["mode"] == "lockstep"
        peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
        queryable = peer.declare_queryable(keys.info, late, complete=True)
        try:
            wait_until(
                lambda: "error" in describe_nodes(loopback.session, ["listed"], prefix=loopback.prefix)[0],
                30,
                "the impostor's info queryable reached",
            )
            listed = describe_nodes(loopback.session, ["listed"], prefix=loopback.prefix, timeout_s=10)[0]
            assert asked and "2 Zenoh sessions answer as node 'listed'" in listed["error"], listed
            assert "mode" not in listed  # neither answer is shown as the node's
        finally:
            queryable.undeclare()
            peer.close()


def test_an_outputs_frame_with_the_wrong_value_count_is_a_transport_error(tmp_path: Path) -> None:
    from bridge.experiment.config import load_experiment
    from bridge.plant.local import LocalFmuPlant

    with LocalFmuPlant(experiment_plant_spec(load_experiment(CARTPOLE))) as plant:
        three = proto.decode(proto.encode_values(proto.OUTPUTS, 1, 1, 0, [0.0, 1.0, 2.0]))
        with pytest.raises(TransportError, match="with 3 values; it serves 4 outputs"):
            answer(plant, three, 1, 1, outputs=4)
        assert answer(plant, three, 1, 1, outputs=3) is three


MODEL_FAILED = b'model_failed: {"what": "w", "detail": "d", "hint": "h", "log": [], "time_s": null}'


def test_a_malformed_reset_reply_is_a_transport_error_naming_the_node(loopback: Loopback) -> None:
    """A session posing as node ``faker`` (its info is a real node's, its own zid, a live token)
    answers resets with short, garbled, unsigned, unkeyed or misdirected step-0 frames: each is a
    TransportError naming the node and what was wrong, never an IndexError or a wrong observation."""
    with experiment_node(CARTPOLE, name="model", options=loopback.options(), prefix=loopback.prefix) as real:  # type: ignore[arg-type]
        described = real.describe()
    peer = open_session(ZenohOptions(connect=(loopback.endpoint,)))
    keys = proto.Keys(loopback.prefix, "faker")
    info = proto.encode_json({**described, "node": "faker", "zid": str(peer.zid())})
    key = bytes(range(proto.KEY_SIZE))
    replies: dict[str, Any] = {}

    def on_reset(query: Any) -> None:
        nonlocal key
        request = query.payload.to_bytes()
        words = json.loads(request)
        pair, client_pub = KeyPair(), bytes.fromhex(words["pub"])  # the key agreement done right
        key = pair.session_key(
            client_pub, client_pub=client_pub, node_pub=pair.public, client=words["client"]
        )
        made = replies["make"](words["episode"])
        if isinstance(made, bytes):  # an error reply
            query.reply_err(made)
            return
        payload, attachment = made
        if attachment is not None:
            proof = reply_proof(key, request, "").hex()
            attachment = proto.encode_json({"pub": pair.public.hex(), "state": "", "proof": proof})
        query.reply(keys.reset, payload, attachment=attachment)

    entities = [
        peer.declare_queryable(keys.info, lambda q: q.reply(keys.info, info), complete=True),
        peer.declare_queryable(keys.reset, on_reset, complete=True),
        peer.liveliness().declare_token(keys.alive),
    ]
    cases = {
        "three values for four outputs": (
            lambda e: (proto.encode_values(proto.OUTPUTS, e, 0, 0, [0.0, 1.0, 2.0], key=key), key),
            "expected 4 values, got 3",
        ),
        "a cut frame": (lambda e: (b"\x01\x02\x03", key), "malformed"),
        "no key agreement": (
            lambda e: (proto.encode_values(proto.OUTPUTS, e, 0, 0, [0.0] * 4), None),
            "attachment",
        ),
        "an unsigned frame": (
            lambda e: (proto.encode_values(proto.OUTPUTS, e, 0, 0, [0.0] * 4), key),
            "not signed with the session key",
        ),
        "another episode": (
            lambda e: (proto.encode_values(proto.OUTPUTS, e + 5, 0, 0, [0.0] * 4, key=key), key),
            "expected the outputs of step 0 of episode",
        ),
        # the model's failure at a reset, as a node says it (bridge.net.node_replies.model_failure)
        "a model failure that is not JSON": (lambda e: b"model_failed: {oops", "must be JSON"),
        "a model failure without its hint": (
            lambda e: b'model_failed: {"what": "w", "detail": "d", "log": [], "time_s": null}',
            "must be JSON with the strings what, detail, hint",
        ),
        "a model failure whose log is not lines": (
            lambda e: MODEL_FAILED.replace(b"[]", b'[1, {"a": 2}]'),
            "a list log",
        ),
        "a model failure at an infinite time": (
            lambda e: MODEL_FAILED.replace(b"null", b"Infinity"),
            "a time_s",
        ),
    }
    try:
        with RemoteFmuEnv(
            CARTPOLE, "faker", session=loopback.session, prefix=loopback.prefix, timeout_s=5
        ) as env:
            for case, (make, says) in cases.items():
                replies["make"] = make
                with pytest.raises(TransportError) as caught:
                    env.reset(seed=1)
                message = str(caught.value)
                assert "node 'faker'" in message and "the reset reply is malformed" in message, (
                    case,
                    message,
                )
                assert says in message, (case, message)
            replies["make"] = lambda e: MODEL_FAILED.replace(b'"d"', b'"the cause"')
            with pytest.raises(StepError) as failed:  # well formed: the model's error, as in process
                env.reset(seed=1)
            assert str(failed.value).startswith("node 'faker': w at reset of episode ")
            assert str(failed.value).endswith(": the cause; h"), str(failed.value)
            replies["make"] = lambda e: (proto.encode_values(proto.OUTPUTS, e, 0, 0, [0.0] * 4, key=key), key)
            obs, _ = env.reset(seed=1)  # a well-formed reply is taken: the check is not a blanket refusal
            assert obs.shape == (4,)
    finally:
        for entity in reversed(entities):
            entity.undeclare()
        peer.close()
