"""Malformed requests on every key of a lockstep and a real-time node (real subprocesses, real Zenoh).

Each request gets a clear error or a correct result: every reset and info query is answered
(ok, or an error that starts with its code and names no local path), every action is accounted
for in the node's counters, no traceback reaches the node's log, its memory stays bounded, and
afterwards a well-behaved client gets the in-process trajectory bit for bit. Seeded and bounded;
the counts go to ``node_fuzz.json`` (see ``tests/reliability_table.py``).
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.handshake import KeyPair
from bridge.net.remote import describe_nodes
from tests.conftest import Loopback, _wait_for_node, wait_until
from tests.reliability_table import counts_file

pytestmark = pytest.mark.integration
SEED = 20260412
CARTPOLE = example_experiment("cartpole_continuous")
COUNTS = counts_file("node_fuzz.json")  # docs/reliability/ only on request (reliability_table.py)
JAZZY = get_typestore(Stores.ROS2_JAZZY)
JOINT_STATE = "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"  # noqa: E501
TRIGGER = (
    "std_srvs::srv::dds_::Trigger_/RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
)
CODES = ("bad_request: ", "busy: ", "failed: ", "unhealthy: ")
PER_NODE = {"reset": 1500, "info": 500, "actions": 2500, "ros_actions": 400, "ros_reset": 100}


@contextlib.contextmanager
def logged_node(net: Loopback, name: str, *extra: str) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    """A node subprocess whose whole log is read as it comes (a full pipe would stall the node)."""
    cmd = [sys.executable, "-m", "bridge.cli", "node", str(CARTPOLE), "--name", name]
    cmd += ["--connect", net.endpoint, "--prefix", net.prefix, "--ros", "--ros-backend", "zenoh", *extra]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines: list[str] = []
    started = threading.Event()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.append(line)
            if "serving" in line:
                started.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        assert started.wait(90), "".join(lines)
        _wait_for_node(net, name, timeout_s=30)
        yield process, lines
    finally:
        process.terminate()
        process.wait(timeout=15)


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


# -- malformed requests ------------------------------------------------------------------------------
def reset_payload(rng: np.random.Generator) -> bytes:
    good: dict[str, Any] = {
        "episode": 3, "values": {"theta0": 0.05}, "inputs": [0.0], "client": 7, "take_over": True,
        "pub": KeyPair().public.hex(),
    }  # fmt: skip  # client 7 has a token (fuzz_node); taking over needs no proof of the last session
    kind = int(rng.integers(14))
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 200)))
    if kind == 1:
        bad = [-1, 2**32, 2**80, 10**400, "1", None, True, 1.5, [], {}]
        return proto.encode_json({**good, "episode": bad[int(rng.integers(len(bad)))]})
    if kind == 2:
        bad_values = [[1, 2], "theta0", 5, None, {"gain": 1e300}, {"/etc/shadow": "x"}]
        bad_values += [{"theta0": "x" * 5000}]
        return proto.encode_json({**good, "values": bad_values[int(rng.integers(len(bad_values)))]})
    if kind == 3:
        huge = [1e300, -1e308, 10**401][int(rng.integers(3))]
        return proto.encode_json({**good, "values": {"theta0": huge}})
    if kind == 4:
        bad_inputs = [[1.0, 2.0], ["a"], "x", [1e308], [None], {}, [True]]
        return proto.encode_json({**good, "inputs": bad_inputs[int(rng.integers(len(bad_inputs)))]})
    if kind == 5:
        return json.dumps({**good, "inputs": [float("nan")]}).encode()  # Python's JSON accepts NaN
    if kind == 6:
        depth = int(rng.choice([50, 5000, 30000]))
        return b'{"values": ' + b"[" * depth + b"]" * depth + b"}"
    if kind == 7:
        return b'{"episode": ' + b"9" * int(rng.integers(300, 5000)) + b"}"
    if kind == 8:
        return proto.encode_json({**good, "client": [-5, 2**64, "me", 0.5][int(rng.integers(4))]})
    if kind == 9:
        return proto.encode_json({**good, "take_over": ["yes", 1, None][int(rng.integers(3))]})
    if kind == 10:
        return proto.encode_json({**good, "unknown": 1})
    if kind == 11:
        return b"x" * int(rng.integers(70_000, 300_000))  # over the size limit
    if kind == 12:
        return proto.encode_json([1, 2, 3])  # type: ignore[arg-type]
    # a well-formed reset from a random client: granted, or refused as busy
    client, take_over = int(rng.integers(1, 2**62)), bool(rng.random() < 0.5)
    return proto.encode_json({**good, "client": client, "take_over": take_over})


def action_payload(rng: np.random.Generator) -> bytes:
    kind = int(rng.integers(9))
    episode, step = int(rng.integers(0, 5)), int(rng.integers(-2, 50))
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 120)))
    if kind == 1:
        return proto.encode_values(int(rng.choice([1, 3, 4, 9])), episode, step, 0, [0.0])
    if kind == 2:
        return proto.encode_values(proto.ACTION, episode, step, 0, rng.random(int(rng.choice([0, 2, 5]))))
    if kind == 3:
        value = [float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 10.5][int(rng.integers(6))]
        return proto.encode_values(proto.ACTION, episode, step, 0, [value])
    if kind == 4:
        return proto.encode_values(proto.ACTION, episode, step, -int(rng.integers(1, 2**62)), [0.0])
    if kind == 5:
        frame = bytearray(proto.encode_values(proto.ACTION, episode, step, 0, [1.0]))
        frame[0] = int(rng.integers(2, 256))  # version
        return bytes(frame)
    if kind == 6:
        return proto.encode_values(proto.ACTION, episode, step, 0, [1.0])[: int(rng.integers(1, 36))]
    client = int(rng.integers(0, 2**62))
    return proto.encode_values(proto.ACTION, episode, step, client, [rng.uniform(-10, 10)])


def joint_state(rng: np.random.Generator) -> bytes:
    kind = int(rng.integers(4))
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 80)))
    header = JAZZY.types["std_msgs/msg/Header"](
        stamp=JAZZY.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
    )
    names = [["force"], ["force", "nothing"], ["x"], []][int(rng.integers(4))]
    values = [float("nan"), 1e308, 3.0, -float("inf")][: len(names) + int(rng.integers(0, 2))]
    message = JAZZY.types["sensor_msgs/msg/JointState"](
        header=header,
        name=names,
        position=np.array(values, dtype=float),
        velocity=np.array([], dtype=float),
        effort=np.array([], dtype=float),
    )
    data = bytes(JAZZY.serialize_cdr(message, "sensor_msgs/msg/JointState"))
    return data if kind != 3 else data[: int(rng.integers(4, len(data)))]


# -- sending and checking ---------------------------------------------------------------------------
def query(session: Any, key: str, payload: bytes, counts: Counter[str], what: str) -> bytes | None:
    replies = list(session.get(key, payload=payload, timeout=10.0))
    counts[f"{what}_sent"] += 1
    assert replies, f"no reply to a {what} request of {len(payload)} bytes: {payload[:80]!r}"
    reply = replies[0]
    if reply.ok is not None:
        counts[f"{what}_ok"] += 1
        return bytes(reply.ok.payload.to_bytes())
    message = reply.err.payload.to_bytes().decode()
    assert message.startswith(CODES), message
    assert "Traceback" not in message and "/tmp/" not in message and "/home/" not in message, message
    counts[f"{what}_error_replies"] += 1
    return None


def fuzz_node(net: Loopback, name: str, rng: np.random.Generator, counts: Counter[str]) -> None:
    session: Any = net.session
    keys = proto.Keys(net.prefix, name)
    ros_actions, ros_reset = f"0/{name}/actions/{JOINT_STATE}", f"0/{name}/reset/{TRIGGER}"
    gid = bytes(range(16))
    token = session.liveliness().declare_token(keys.client(7))  # a lease is backed by a token
    for i in range(PER_NODE["reset"]):
        answer = query(session, keys.reset, reset_payload(rng), counts, "reset")
        if answer is not None:
            frame = proto.decode(answer)
            assert frame.kind == proto.OUTPUTS and frame.step == 0 and np.isfinite(frame.values).all()
        if i % 3 == 0:
            for _ in range(PER_NODE["actions"] // 500):
                session.put(keys.actions, action_payload(rng))
                counts["actions_sent"] += 1
    for _ in range(PER_NODE["info"]):
        size = int(rng.choice([0, 0, 1, 65, 1000, 70_000]))
        answer = query(session, keys.info, rng.bytes(size) if size else b"", counts, "info")
        if answer is not None:
            assert json.loads(answer)["node"] == name
    while counts["actions_sent"] < PER_NODE["actions"] * (1 + (counts["nodes_done"])):
        session.put(keys.actions, action_payload(rng))
        counts["actions_sent"] += 1
    for seq in range(PER_NODE["ros_actions"]):
        attachment = struct.pack("<qqB16s", seq, time.time_ns(), 16, gid)
        session.put(ros_actions, joint_state(rng), attachment=attachment)
        counts["ros_actions_sent"] += 1
    for seq in range(PER_NODE["ros_reset"]):
        request = [bytes.fromhex("0001000000"), rng.bytes(int(rng.integers(0, 300)))][seq % 2]
        attachment = struct.pack("<qqB16s", seq, time.time_ns(), 16, gid)
        replies = list(session.get(ros_reset, payload=request, timeout=10.0, attachment=attachment))
        counts["ros_reset_sent"] += 1
        assert replies, "a ROS reset got no reply"
        if replies[0].ok is None:  # the service layer refuses what is not CDR, with a reason
            message = replies[0].err.payload.to_bytes().decode()
            assert message.startswith("service ") and "rejected the request" in message, message
            counts["ros_reset_error_replies"] += 1
            continue
        payload = bytes(replies[0].ok.payload.to_bytes())
        assert payload[:4] == b"\x00\x01\x00\x00"
        counts["ros_reset_ok" if payload[4] == 1 else "ros_reset_refused"] += 1
    token.undeclare()
    counts["nodes_done"] += 1


def accounted(counters: dict[str, int], realtime: bool) -> int:
    """Actions the node counted one way or another (stepped or held, duplicate, rejected, malformed)."""
    keys = ("held" if realtime else "steps", "duplicate", "malformed")
    rejected = sum(v for k, v in counters.items() if k.startswith("rejected_"))
    return sum(counters.get(k, 0) for k in keys) + rejected


def trajectory(env: Any, seed: int, steps: int = 30) -> np.ndarray:
    rows = [env.reset(seed=seed)[0]]
    for i in range(steps):
        obs, reward, terminated, truncated, _ = env.step(np.array([0.3 * np.sin(i)], dtype=np.float32))
        rows.append(np.append(obs, reward))
        if terminated or truncated:
            break
    return np.concatenate(rows)


def test_malformed_requests_on_every_key_get_clear_answers_and_nodes_keep_serving(loopback: Loopback) -> None:
    rng = np.random.default_rng(SEED)
    counts: Counter[str] = Counter()
    with (
        logged_node(loopback, "lock") as (lock, lock_log),
        logged_node(loopback, "rt", "--mode", "realtime", "--rate", "2") as (rt, rt_log),
    ):
        rss_before = {p.pid: rss_mb(p.pid) for p in (lock, rt)}
        start = time.monotonic()
        for name in ("lock", "rt"):
            fuzz_node(loopback, name, rng, counts)
        elapsed = time.monotonic() - start
        sent_actions = counts["actions_sent"]

        def described() -> dict[str, Any]:
            return {
                e["node"]: e
                for e in describe_nodes(
                    loopback.session, ["lock", "rt"], prefix=loopback.prefix, timeout_s=10
                )
            }

        def all_counted() -> bool:  # the last puts may still be on their way
            infos.update(described())
            return (
                accounted(infos["lock"]["counters"], False) + accounted(infos["rt"]["counters"], True)
                >= sent_actions
            )

        infos: dict[str, Any] = {}
        wait_until(all_counted, 60, "every fuzzed action counted by the nodes")
        growth = {p.pid: rss_mb(p.pid) - rss_before[p.pid] for p in (lock, rt)}
        env = RemoteFmuEnv(CARTPOLE, "lock", session=loopback.session, prefix=loopback.prefix, take_over=True)
        try:
            with FmuEnv(CARTPOLE) as local:
                np.testing.assert_array_equal(trajectory(env, 2), trajectory(local, 2))
        finally:
            env.close()
        rt_steps = infos["rt"]["counters"]["steps"]

        def rt_now() -> int:
            return int(
                describe_nodes(loopback.session, ["rt"], prefix=loopback.prefix, timeout_s=10)[0]["counters"][
                    "steps"
                ]
            )

        wait_until(lambda: rt_now() > rt_steps, 30, "the real-time node advancing")
        assert lock.poll() is None and rt.poll() is None
    tracebacks = sum("Traceback" in line for line in lock_log + rt_log)
    counted = accounted(infos["lock"]["counters"], False) + accounted(infos["rt"]["counters"], True)
    assert counted == sent_actions, (counted, sent_actions, [infos[n]["counters"] for n in infos])
    assert all(infos[n]["health"] == "ok" for n in infos), infos
    assert tracebacks == 0, "".join(lock_log + rt_log)[-3000:]
    assert max(growth.values()) < 100, growth  # first-use buffers; a leak per request would be far more
    requests = sum(v for k, v in counts.items() if k.endswith("_sent"))
    assert requests >= 10_000 and elapsed < 120, (requests, elapsed)
    COUNTS.write_text(
        json.dumps(
            {
                "seed": SEED,
                "nodes": ["lockstep", "realtime"],
                "requests": requests,
                **{k: v for k, v in sorted(counts.items()) if k != "nodes_done"},
                "actions_accounted_by_the_nodes": counted,
                "fuzz_seconds": round(elapsed, 1),
                "rss_growth_mb_max": round(max(growth.values()), 1),
                "tracebacks": tracebacks,
                "hangs": 0,
                "silently_wrong": 0,
                "well_behaved_client_bit_for_bit": True,
            },
            indent=2,
        )
        + "\n"
    )
