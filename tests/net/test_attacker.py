"""An admitted but hostile participant against the session protocol (docs/protocol.md).

The attacker declares queryables on the node's reset and state keys and subscribes to its
actions key, so it captures every reset, state and action frame a victim sends; between the
victim's episodes and in the middle of them it replays each one, verbatim and altered, into
the same session and into later ones. The victim's 20 episodes must equal those of the same
experiment in process, bit for bit, the victim keeps the node throughout, and nothing the
attacker captured or was answered contains a session key. Run on loopback and on the documented
user/password and TLS routers (launch_scripts/zenoh/), with real nodes and real Zenoh sessions
on 127.0.0.1.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session
from bridge.plant.state_run import save_state
from bridge.serving import experiment_node
from tests.conftest import free_port, router_on_loopback, wait_until
from tests.net.test_transport import client_config, make_certificates, render, router_config

pytestmark = pytest.mark.integration
ACTIONS = [1.0, -1.0, 0.0, 1.0, 1.0, -1.0, 0.0, -1.0]
EPISODES, SESSIONS = 20, 2


def _experiment(tmp_path: Path, name: str, **model: object) -> Path:
    data = {
        "name": name,
        "model": {
            "fmu": "example:slow_init:2.0:cs",
            "step_size": 0.05,
            "episode_duration": 2.0,
            "parameters": {"warmup_steps": 0},
            **model,
        },
        "actions": {"inputs": ["power"], "low": {"power": -50.0}, "high": {"power": 50.0}},
        "observations": {"outputs": ["T"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@dataclass
class Net:
    prefix: str
    options: ZenohOptions
    attacker: ZenohOptions


@contextlib.contextmanager
def _usrpwd(tmp_path: Path) -> Iterator[Net]:
    port = str(free_port())
    (tmp_path / "credentials.txt").write_text("worker:s3cret\nintruder:itsown\n")
    router_cfg = render(
        "router_usrpwd.json5", tmp_path, **{"0.0.0.0:7447": f"127.0.0.1:{port}", "CHANGE_ME": "routerpw"}
    )
    user = {"ROUTER_HOST": "127.0.0.1", ":7447": f":{port}"}
    (tmp_path / "victim").mkdir()
    (tmp_path / "intruder").mkdir()
    victim = render("client_usrpwd.json5", tmp_path / "victim", CHANGE_ME="s3cret", **user)
    intruder = render("client_usrpwd.json5", tmp_path / "intruder", CHANGE_ME="itsown", **user)
    intruder.write_text(intruder.read_text().replace('"worker"', '"intruder"'))  # its own account
    cwd = os.getcwd()
    os.chdir(tmp_path)  # the dictionary file is relative to the working directory
    try:
        router = open_session(ZenohOptions(config_file=router_cfg))
    finally:
        os.chdir(cwd)
    try:
        yield Net(
            f"usr_{uuid.uuid4().hex[:8]}",
            ZenohOptions(config_file=victim),
            ZenohOptions(config_file=intruder),
        )
    finally:
        router.close()


@contextlib.contextmanager
def _tls(tmp_path: Path) -> Iterator[Net]:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make test certificates")
    make_certificates(tmp_path)
    port = str(free_port())
    router = open_session(ZenohOptions(config_file=router_config("router_tls.json5", tmp_path, port)))
    try:
        options = ZenohOptions(config_file=client_config("client_tls.json5", tmp_path, port))
        yield Net(f"tls_{uuid.uuid4().hex[:8]}", options, options)
    finally:
        router.close()


@contextlib.contextmanager
def _loopback() -> Iterator[Net]:
    with router_on_loopback() as net:
        options = ZenohOptions(connect=(net.endpoint,))
        yield Net(net.prefix, options, options)


@pytest.fixture(params=["loopback", "usrpwd", "tls"])
def network(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Net]:
    setups = {"loopback": _loopback, "usrpwd": lambda: _usrpwd(tmp_path), "tls": lambda: _tls(tmp_path)}
    with setups[request.param]() as net:
        yield net


@dataclass
class Attacker:
    """Captures every reset, state and action frame sent to ``node`` and plays them back."""

    session: Any
    keys: proto.Keys
    captured: dict[str, list[tuple[bytes, bytes | None]]] = field(
        default_factory=lambda: {"reset": [], "state": [], "actions": []}
    )
    received: list[bytes] = field(default_factory=list)  # every byte answered to the attacker
    answered_ok: int = 0
    replayed: dict[str, int] = field(default_factory=lambda: {"reset": 0, "state": 0, "actions": 0})
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _replaying: bool = False  # its own replays reach its own queryables: not captured

    def __post_init__(self) -> None:
        self._entities = [
            self.session.declare_queryable(self.keys.reset, lambda q: self._capture("reset", q)),
            self.session.declare_queryable(self.keys.state, lambda q: self._capture("state", q)),
            self.session.declare_subscriber(self.keys.actions, lambda s: self._capture("actions", s)),
        ]

    def _capture(self, kind: str, message: Any) -> None:
        payload = message.payload.to_bytes() if message.payload is not None else b""
        attachment = message.attachment.to_bytes() if message.attachment is not None else None
        with self._lock:
            if not self._replaying and (payload, attachment) not in self.captured[kind]:
                self.captured[kind].append((payload, attachment))

    def frames(self, kind: str) -> list[tuple[bytes, bytes | None]]:
        with self._lock:
            return list(self.captured[kind])

    def replay(self, everything: bool = False) -> None:
        """The frames captured since the last replay (``everything``: all so far, into a later
        session) again: verbatim, and altered in every field an attacker could change without
        the session key."""
        self._replaying = True
        try:
            self._replay({k: 0 if everything else n for k, n in self.replayed.items()})
        finally:
            self._replaying = False
        self.replayed = {k: len(v) for k, v in self.captured.items()}

    def _replay(self, since: dict[str, int]) -> None:
        for payload, attachment in self.frames("reset")[since["reset"] :]:
            for variant in _reset_variants(payload):
                for attached in (attachment, None):
                    self._query(self.keys.reset, variant, attached)
        for payload, attachment in self.frames("state")[since["state"] :]:
            cut = payload[:-1] + bytes([payload[-1] ^ 1]) if payload else payload
            for variant in (payload, cut):
                self._query(self.keys.state, variant, attachment)
        for payload, _ in self.frames("actions")[since["actions"] :]:
            self.session.put(self.keys.actions, payload)
            altered = bytearray(payload)
            if len(altered) > proto.HEADER.size + 8:
                altered[proto.HEADER.size + 5] ^= 0x40  # a value changed, the MAC kept
                self.session.put(self.keys.actions, bytes(altered))

    def _query(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        for reply in self.session.get(key, payload=payload, attachment=attachment, timeout=10.0):
            if reply.ok is not None:
                self.answered_ok += 1
                self.received.append(reply.ok.payload.to_bytes())
                if reply.ok.attachment is not None:
                    self.received.append(reply.ok.attachment.to_bytes())
            else:
                self.received.append(reply.err.payload.to_bytes())

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()


def _reset_variants(payload: bytes) -> list[bytes]:
    """A captured reset verbatim, and altered: other values, another episode, a take-over, the
    next request number, the attacker's own key-agreement key."""
    words = json.loads(payload)
    altered = [
        {**words, "values": {"T0": 400.0}} if "values" in words else {**words, "values": {}},
        {**words, "episode": int(words.get("episode", 0)) + 1},
        {**words, "take_over": True},
        {**words, "seq": int(words.get("seq", 0)) + 1},
        {**words, "pub": "11" * 32},
    ]
    return [payload, *(proto.encode_json(w) for w in altered)]


def _episode(env: FmuEnv | RemoteFmuEnv, seed: int, midway: Any = None) -> np.ndarray:
    _, info = env.reset(seed=seed)
    rows = [[info["time_s"], *info["outputs"]]]
    for i, a in enumerate(ACTIONS):
        _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        rows.append([info["time_s"], *info["outputs"]])
        if midway is not None and i == len(ACTIONS) // 2:
            midway()
    episode = np.array(rows)
    episode[:, 0] = np.round(episode[:, 0] * 1e9) / 1e9  # a node sends time in whole nanoseconds
    return episode


def test_a_participant_replaying_every_frame_changes_no_episode_and_learns_no_key(
    network: Net, tmp_path: Path
) -> None:
    saved = save_state(
        load_experiment(_experiment(tmp_path, "saver")), tmp_path / "s.state", until_s=1.5
    ).path
    served = _experiment(tmp_path, "served")
    wanted = _experiment(tmp_path, "wanted", reset_policy={"state_file": str(saved)})
    with FmuEnv(wanted) as local:
        reference = [_episode(local, seed) for seed in range(EPISODES)]
    victim_session = open_session(network.options)
    attacker_session = open_session(network.attacker)
    keys = proto.Keys(network.prefix, "victim")
    attacker = Attacker(attacker_session, keys)
    episodes, session_keys = [], []
    try:
        with experiment_node(
            served, name="victim", options=network.options, prefix=network.prefix, isolate=True
        ) as node:
            for _ in range(SESSIONS):  # a later session: the victim's env opened again
                with RemoteFmuEnv(
                    wanted, "victim", session=victim_session, prefix=network.prefix, timeout_s=60
                ) as env:
                    client: Any = env._remote.client
                    first = len(episodes)
                    for seed in range(first, first + EPISODES // SESSIONS):
                        episodes.append(_episode(env, seed, midway=attacker.replay))
                        attacker.replay(everything=seed == first)  # into the same and later sessions
                        assert node.lease.holder is not None and node.lease.holder.client == client.client_id
                    session_keys.append(client.key)
            assert node.lease.takeovers == 0
            counters = dict(node.counters)
    finally:
        attacker.close()
        attacker_session.close()
        victim_session.close()
    changed = [i for i, (got, want) in enumerate(zip(episodes, reference)) if not np.array_equal(got, want)]
    assert changed == [], f"victim episodes changed by replays: {changed}"
    assert all(attacker.frames(k) for k in ("reset", "state", "actions")), "the attacker saw no traffic"
    learnt = b"".join(attacker.received) + b"".join(
        p + (a or b"") for k in attacker.captured.values() for p, a in k
    )
    assert all(key is not None and key not in learnt for key in session_keys)
    assert counters.get("reset_busy", 0) > 0 and counters.get("state_busy", 0) > 0  # refused, and counted


def test_crafted_states_crash_no_node_and_change_no_other_clients_episode(tmp_path: Path) -> None:
    """States that pass every check the node can make (random bytes resealed with a valid
    checksum, counts of 2^31) are loaded only in the isolated child: at worst the sender's own
    resets fail; the node lives on, and the next client's episodes are exact."""
    from bridge.fmu import state_file

    saved = save_state(
        load_experiment(_experiment(tmp_path, "saver")), tmp_path / "s.state", until_s=1.5
    ).path
    good = state_file.read(saved)
    served = _experiment(tmp_path, "served")
    rng = np.random.default_rng(5)
    other = save_state(
        load_experiment(_experiment(tmp_path, "other", fmu="example:slow_init:3.0:cs")),
        tmp_path / "o.state",
        until_s=0.5,
    ).path.read_bytes()
    crafted = [
        state_file.encode(*_sealed(good.header, rng.bytes(len(good.payload)))),  # random bytes resealed
        state_file.encode(*_sealed(good.header, b"\xff" * len(good.payload))),  # huge counts
        state_file.encode(*_sealed(good.header, b"")),
        other,  # another FMU's state
        saved.read_bytes()[:-7],  # cut
    ]
    with FmuEnv(served) as local:
        reference = [_episode(local, seed) for seed in range(3)]
    with router_on_loopback() as net:
        options = ZenohOptions(connect=(net.endpoint,))
        with experiment_node(served, name="target", options=options, prefix=net.prefix, isolate=True) as node:
            for data in crafted:
                with RemoteFmuEnv(
                    served, "target", session=net.session, prefix=net.prefix, timeout_s=60
                ) as hostile:
                    hostile.reset(seed=0)
                    with contextlib.suppress(Exception):  # refused, or taken: the child may die of it
                        hostile.start_from(data)
                        hostile.reset(seed=1)
                assert node.describe()["node"] == "target"  # the node lives
            with RemoteFmuEnv(
                served, "target", session=net.session, prefix=net.prefix, timeout_s=60
            ) as victim:
                episodes = [_episode(victim, seed) for seed in range(3)]
            assert node.describe()["start_state"] == ""
    for got, want in zip(episodes, reference):
        np.testing.assert_array_equal(got, want)


def _sealed(header: Any, payload: bytes) -> tuple[Any, bytes]:
    from bridge.fmu import state_file

    return state_file.seal(header, payload).header, payload


ACL = """
  access_control: {
    enabled: true,
    default_permission: "deny",
    rules: [
      { id: "serve_and_drive", permission: "allow", flows: ["egress", "ingress"],
        messages: ["put", "delete", "declare_subscriber", "declare_queryable", "query", "reply",
                   "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"],
        key_exprs: ["PREFIX/**"] },
      { id: "watch", permission: "allow", flows: ["egress", "ingress"],
        messages: ["put", "declare_subscriber", "query", "reply", "liveliness_token", "liveliness_query",
                   "declare_liveliness_subscriber"],
        key_exprs: ["PREFIX/*/outputs", "PREFIX/*/info", "PREFIX/*/alive"] },
    ],
    subjects: [ { id: "workers", usernames: ["worker"] }, { id: "viewers", usernames: ["viewer"] } ],
    policies: [
      { id: "workers_serve", rules: ["serve_and_drive"], subjects: ["workers"] },
      { id: "viewers_watch", rules: ["watch"], subjects: ["viewers"] },
    ],
  },
}"""


def test_zenoh_access_control_keeps_a_viewer_away_from_the_node_keys(tmp_path: Path) -> None:
    """docs/protocol.md's per-user access control on the user/password router: a ``viewer`` may
    list the node and watch its outputs, but never receives a reset request and cannot act."""
    port, prefix = str(free_port()), f"acl_{uuid.uuid4().hex[:8]}"
    (tmp_path / "credentials.txt").write_text("worker:s3cret\nviewer:look\n")
    router_cfg = render(
        "router_usrpwd.json5", tmp_path, **{"0.0.0.0:7447": f"127.0.0.1:{port}", "CHANGE_ME": "routerpw"}
    )
    text = router_cfg.read_text().rstrip()
    router_cfg.write_text(text[: text.rindex("}")] + ACL.replace("PREFIX", prefix) + "\n")
    user = {"ROUTER_HOST": "127.0.0.1", ":7447": f":{port}"}
    (tmp_path / "w").mkdir()
    (tmp_path / "v").mkdir()
    worker = render("client_usrpwd.json5", tmp_path / "w", CHANGE_ME="s3cret", **user)
    viewer = render("client_usrpwd.json5", tmp_path / "v", CHANGE_ME="look", **user)
    viewer.write_text(viewer.read_text().replace('"worker"', '"viewer"'))
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        router = open_session(ZenohOptions(config_file=router_cfg))
    finally:
        os.chdir(cwd)
    served = _experiment(tmp_path, "served")
    victim_session = open_session(ZenohOptions(config_file=worker))
    viewer_session = open_session(ZenohOptions(config_file=viewer))
    keys = proto.Keys(prefix, "guarded")
    attacker = Attacker(viewer_session, keys)
    seen: list[bytes] = []
    watcher = viewer_session.declare_subscriber(keys.outputs, lambda s: seen.append(s.payload.to_bytes()))
    try:
        options = ZenohOptions(config_file=worker)
        with (
            experiment_node(served, name="guarded", options=options, prefix=prefix) as node,
            RemoteFmuEnv(served, "guarded", session=victim_session, prefix=prefix, timeout_s=30) as env,
        ):
            with FmuEnv(served) as local:
                reference = _episode(local, 4)
            np.testing.assert_array_equal(_episode(env, 4), reference)
            forged = proto.encode_values(proto.ACTION, 1, 9, 0, [0.0])
            viewer_session.put(keys.actions, forged)  # denied by the router: never reaches the node
            np.testing.assert_array_equal(_episode(env, 4), reference)
            wait_until(lambda: len(seen) >= 2 * (len(ACTIONS) + 1), 30, "the viewer watching the outputs")
            assert attacker.frames("reset") == []  # its queryable was refused by the router
            assert [p for p, _ in attacker.frames("actions")] in ([], [forged])  # its own put only
            assert "rejected_not_holder" not in node.counters and "malformed" not in str(node.counters)
    finally:
        watcher.undeclare()
        attacker.close()
        viewer_session.close()
        victim_session.close()
        router.close()
