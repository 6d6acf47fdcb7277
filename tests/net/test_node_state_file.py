"""A node starts its episodes from a state file handed to it over the wire (or named in its own
experiment): the episodes equal, bit for bit, those from the in-memory snapshot of the run that
saved it; foreign, cut, oversized or unauthenticated states are refused before the FMU sees them.
A state is the holder's alone: it is loaded only by an isolated node's child, ends with the lease
it was sent in, and the node names it (``info`` and every reset reply); crafted states that pass
every check crash at most that child, never the node or another client's episode.

Real nodes in this process on a Zenoh router on 127.0.0.1."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import PlantDied, TransportError
from bridge.experiment.config import load_experiment
from bridge.fmu import Model
from bridge.net import node_start
from bridge.net import protocol as proto
from bridge.net.handshake import request_proof
from bridge.net.remote import RemotePlant
from bridge.net.requests import BadRequest, Refused
from bridge.plant.state_run import save_state
from bridge.serving import experiment_node
from tests.conftest import Loopback, example_fmu

pytestmark = pytest.mark.integration
SAVED_AT = 1.5  # s
ACTIONS = [1.0, -1.0, 0.0, 1.0, 1.0, -1.0, 0.0, -1.0]  # physical powers 50, -50, 0 W: exact


def _experiment(tmp_path: Path, name: str, version: str = "2.0", **model: object) -> Path:
    data = {
        "name": name,
        "model": {
            "fmu": f"example:slow_init:{version}:cs",
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


def _snapshot_episode() -> np.ndarray:
    """The reference: the run that saved the state, restored from its in-memory snapshot."""
    with Model(example_fmu("slow_init", "2.0", "cs"), step_size_s=0.05) as m:
        m.initialize({"warmup_steps": 0})
        m.advance(round(SAVED_AT / 0.05))
        snapshot = m.save_state()
        m.advance(11)  # move on, so that the restore has something to undo
        m.restore_state(snapshot)
        rows = [[m.time_s, m.get(["T"])["T"]]]
        for a in ACTIONS:
            m.set({"power": 50.0 * a})
            m.advance(1)
            rows.append([m.time_s, m.get(["T"])["T"]])
    episode = np.array(rows)
    episode[:, 0] = np.round(episode[:, 0] * 1e9) / 1e9
    return episode


def _env_episode(env: FmuEnv | RemoteFmuEnv) -> np.ndarray:
    """Time and the unscaled float64 output T (``info["outputs"]``) of each sample; a node sends
    time in whole nanoseconds, so times are rounded to them here (the outputs are not)."""
    _, info = env.reset(seed=3)
    rows = [[info["time_s"], *info["outputs"]]]
    for a in ACTIONS:
        _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        rows.append([info["time_s"], *info["outputs"]])
    episode = np.array(rows)
    episode[:, 0] = np.round(episode[:, 0] * 1e9) / 1e9
    return episode


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    run = save_state(load_experiment(_experiment(tmp_path, "saver")), tmp_path / "s.state", until_s=SAVED_AT)
    assert run.header.time_s == SAVED_AT
    return run.path


def test_node_given_a_state_over_the_wire_equals_the_in_memory_snapshot(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    served = _experiment(tmp_path, "plain")  # the node's own file names no state
    wanted = _experiment(tmp_path, "from_state", reset_policy={"state_file": "s.state"})
    reference = _snapshot_episode()
    with (
        experiment_node(
            served, name="st", options=loopback.options(), prefix=loopback.prefix, isolate=True
        ) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(wanted, "st", session=loopback.session, prefix=loopback.prefix, timeout_s=60) as remote,
        FmuEnv(wanted) as local,
    ):
        assert node.counters["states_taken"] == 0  # only a holder sends one: at the first reset
        for _ in range(2):  # every episode starts from the state
            np.testing.assert_array_equal(_env_episode(remote), reference)
        np.testing.assert_array_equal(_env_episode(local), reference)
        assert node.counters["states_taken"] == 1
        sha = hashlib.sha256(saved.read_bytes()).hexdigest()
        assert node.describe()["start_state"] == sha  # info and the reset reply name it
        assert remote._remote.client.start_state == sha
    assert reference[0, 0] == SAVED_AT and reference[-1, 1] != reference[0, 1]


def test_node_with_a_state_file_in_its_experiment_starts_from_it(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    served = _experiment(tmp_path, "node_state", reset_policy={"state_file": str(saved)})
    with (
        experiment_node(served, name="own", options=loopback.options(), prefix=loopback.prefix),  # type: ignore[arg-type]
        RemoteFmuEnv(
            _experiment(tmp_path, "client_plain"), "own", session=loopback.session, prefix=loopback.prefix
        ) as remote,
    ):
        np.testing.assert_array_equal(_env_episode(remote), _snapshot_episode())


def test_node_refuses_foreign_cut_and_unauthenticated_states(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    good = saved.read_bytes()
    other = save_state(
        load_experiment(_experiment(tmp_path, "other", version="3.0")), tmp_path / "o.state", until_s=0.5
    ).path.read_bytes()
    options: Any = loopback.options()
    with (
        experiment_node(
            _experiment(tmp_path, "n"), name="ref", options=options, prefix=loopback.prefix, isolate=True
        ) as node,
        RemoteFmuEnv(
            _experiment(tmp_path, "c"), "ref", session=loopback.session, prefix=loopback.prefix, timeout_s=60
        ) as env,
    ):
        plant = env.plant
        assert isinstance(plant, RemotePlant)
        client = plant.client
        with pytest.raises(TransportError, match="only the holder of a node may send it"):
            client.send_state(good)  # nobody holds the node: nobody may send it a state
        with pytest.raises(Refused, match="only the holder's session"):
            node_start.take_state(node, node_start.encode_request(0, 1, good))  # anonymous, unheld
        env.reset(seed=0)  # the client holds the node now: only its session may send a state
        with pytest.raises(TransportError, match="saved by another FMU"):
            client.send_state(other)
        with pytest.raises(TransportError, match="cut"):
            client.send_state(good[:-3])
        assert node.counters["states_taken"] == 0
        assert client.send_state(good)["time_s"] == SAVED_AT  # signed with its session key
        assert client.key is not None
        sent = node_start.encode_request(client.client_id, client._seq, good)
        with pytest.raises(Refused, match="used already"):  # the holder's own request, replayed
            node_start.take_state(node, sent, request_proof(client.key, "state", sent))
        later = node_start.encode_request(client.client_id, client._seq + 1, good)
        with pytest.raises(Refused, match="signature is wrong"):  # its id and number, not its key
            node_start.take_state(node, later, request_proof(b"\0" * proto.KEY_SIZE, "state", later))
        with pytest.raises(Refused, match="only the holder's session"):
            node_start.take_state(node, node_start.encode_request(0, 99, good))
        with pytest.raises(BadRequest, match="more than the limit"):
            node_start.take_state(node, b"\0" * (proto.MAX_STATE_BYTES + 1))
        with pytest.raises(BadRequest, match="JSON part claims"):
            node_start.take_state(node, b"\xff\xff\xff\xff{}")
        assert node.counters["states_taken"] == 1


def test_a_node_running_its_fmu_in_its_own_process_loads_no_sent_state(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    """The FMU deserialises a state's bytes: a node whose FMU runs in the node's own process
    refuses a sent state (a crafted one could crash it), naming the option that allows it."""
    options: Any = loopback.options()
    with (
        experiment_node(
            _experiment(tmp_path, "n"), name="inproc", options=options, prefix=loopback.prefix
        ) as node,
        RemoteFmuEnv(
            _experiment(tmp_path, "c"), "inproc", session=loopback.session, prefix=loopback.prefix
        ) as env,
    ):
        env.reset(seed=0)
        with pytest.raises(TransportError, match=r"loaded only in an isolated child.*--isolate"):
            env.start_from(saved)
        assert node.counters["states_taken"] == 0 and node.describe()["start_state"] == ""


def _initialised_episode(tmp_path: Path) -> np.ndarray:
    """The episode without a state: initialisation at t0 = 0 (the experiment's own start)."""
    env = FmuEnv(_experiment(tmp_path, "init_reference"))
    try:
        return _env_episode(env)
    finally:
        env.close()


def test_a_take_over_sends_its_state_as_the_new_holder(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    """A node held by another client refuses a state from anyone but its holder: an env opened
    with take_over=True takes the node over first, then sends its state, then starts from it."""
    served = _experiment(tmp_path, "held")
    wanted = _experiment(tmp_path, "taker", reset_policy={"state_file": "s.state"})
    with (
        experiment_node(
            served, name="held", options=loopback.options(), prefix=loopback.prefix, isolate=True
        ) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(served, "held", session=loopback.session, prefix=loopback.prefix, timeout_s=60) as first,
    ):
        first.reset(seed=0)  # the first env holds the node
        with (  # without take_over the node stays the first's
            RemoteFmuEnv(
                wanted, "held", session=loopback.session, prefix=loopback.prefix, timeout_s=60
            ) as second,
            pytest.raises(TransportError, match="busy"),
        ):
            second.reset(seed=0)
        assert node.counters["states_taken"] == 0
        with RemoteFmuEnv(
            wanted, "held", session=loopback.session, prefix=loopback.prefix, timeout_s=60, take_over=True
        ) as taker:
            for _ in range(2):
                np.testing.assert_array_equal(_env_episode(taker), _snapshot_episode())
        assert node.counters["states_taken"] == 1
        assert node.lease.takeovers >= 1


def test_an_isolated_node_takes_a_state_over_the_wire_and_clears_it(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    """The isolated node's child process gets the state: its episodes equal the in-memory
    snapshot's bit for bit, also after the child is restarted; a clear goes back to initialisation."""
    served = _experiment(tmp_path, "plain_isolated")
    with (
        experiment_node(
            served, name="iso", options=loopback.options(), prefix=loopback.prefix, isolate=True
        ) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(served, "iso", session=loopback.session, prefix=loopback.prefix, timeout_s=60) as remote,
    ):
        assert node.isolated
        answer = remote.start_from(saved)  # not the holder yet: it goes with the first reset
        assert answer["time_s"] == SAVED_AT and answer["pending"] and node.counters["states_taken"] == 0
        reference = _snapshot_episode()
        np.testing.assert_array_equal(_env_episode(remote), reference)
        plant: Any = node.plant
        plant._kill()  # the child dies (as a crashed FMU's would); the next reset starts a fresh one
        plant._broken = PlantDied("killed by the test")
        np.testing.assert_array_equal(_env_episode(remote), reference)
        assert plant.restarts == 1 and node.counters["states_taken"] == 1
        assert remote.clear_start() == {"cleared": True}
        np.testing.assert_array_equal(_env_episode(remote), _initialised_episode(tmp_path))
        assert node.counters["states_cleared"] == 1


def test_clearing_a_sent_state_goes_back_to_the_experiments_own_start(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    other = save_state(
        load_experiment(_experiment(tmp_path, "other_time")), tmp_path / "o.state", until_s=0.5
    ).path
    options: Any = loopback.options()
    with (
        experiment_node(
            _experiment(tmp_path, "p"), name="clr", options=options, prefix=loopback.prefix, isolate=True
        ) as plain,
        experiment_node(
            _experiment(tmp_path, "own", reset_policy={"state_file": str(saved)}),
            name="own_clr",
            options=options,
            prefix=loopback.prefix,
            isolate=True,
        ),
        RemoteFmuEnv(
            _experiment(tmp_path, "c1"), "clr", session=loopback.session, prefix=loopback.prefix
        ) as env,
        RemoteFmuEnv(
            _experiment(tmp_path, "c2"), "own_clr", session=loopback.session, prefix=loopback.prefix
        ) as own,
    ):
        initialised = _initialised_episode(tmp_path)
        env.start_from(saved.read_bytes())
        np.testing.assert_array_equal(_env_episode(env), _snapshot_episode())
        # held now: a clear must come from the holder's session
        client: Any = env._remote.client
        with pytest.raises(Refused, match="only the holder's session"):
            node_start.take_state(plain, node_start.encode_request(0, 50, None))
        clear = node_start.encode_request(client.client_id, 50, None)
        with pytest.raises(Refused, match="signature is wrong"):
            node_start.take_state(plain, clear, request_proof(b"\0" * proto.KEY_SIZE, "state", clear))
        with pytest.raises(BadRequest, match="carries no state"):
            node_start.take_state(plain, clear + b"x", request_proof(client.key, "state", clear + b"x"))
        assert env.clear_start() == {"cleared": True}
        for _ in range(2):
            np.testing.assert_array_equal(_env_episode(env), initialised)
        assert env.clear_start() == {"cleared": True}  # nothing to clear: still fine
        np.testing.assert_array_equal(_env_episode(env), initialised)

        # a node whose own experiment names a state file: a clear goes back to that one
        own.start_from(other)
        episode = _env_episode(own)
        assert episode[0, 0] == 0.5
        own.clear_start()
        np.testing.assert_array_equal(_env_episode(own), _snapshot_episode())
