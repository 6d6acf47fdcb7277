"""A node starts its episodes from a state file handed to it over the wire (or named in its own
experiment): the episodes equal, bit for bit, those from the in-memory snapshot of the run that
saved it; foreign, cut, oversized or unauthenticated states are refused before the FMU sees them.

Real nodes in this process on a Zenoh router on 127.0.0.1."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import TransportError
from bridge.experiment.config import load_experiment
from bridge.fmu import Model
from bridge.net import node_start
from bridge.net import protocol as proto
from bridge.net.node import FmuNode
from bridge.net.remote import RemotePlant
from bridge.net.requests import BadRequest, Refused
from bridge.plant.state_run import save_state
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
        FmuNode(served, name="st", options=loopback.options(), prefix=loopback.prefix) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(wanted, "st", session=loopback.session, prefix=loopback.prefix, timeout_s=20) as remote,
        FmuEnv(wanted) as local,
    ):
        assert node.counters["states_taken"] == 1
        for _ in range(2):  # every episode starts from the state
            np.testing.assert_array_equal(_env_episode(remote), reference)
        np.testing.assert_array_equal(_env_episode(local), reference)
    assert reference[0, 0] == SAVED_AT and reference[-1, 1] != reference[0, 1]


def test_node_with_a_state_file_in_its_experiment_starts_from_it(
    loopback: Loopback, tmp_path: Path, saved: Path
) -> None:
    served = _experiment(tmp_path, "node_state", reset_policy={"state_file": str(saved)})
    with (
        FmuNode(served, name="own", options=loopback.options(), prefix=loopback.prefix),  # type: ignore[arg-type]
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
        FmuNode(_experiment(tmp_path, "n"), name="ref", options=options, prefix=loopback.prefix) as node,
        RemoteFmuEnv(
            _experiment(tmp_path, "c"), "ref", session=loopback.session, prefix=loopback.prefix
        ) as env,
    ):
        plant = env.plant
        assert isinstance(plant, RemotePlant)
        client = plant.client
        with pytest.raises(TransportError, match="saved by another FMU"):
            client.send_state(other)
        with pytest.raises(TransportError, match="cut"):
            client.send_state(good[:-3])
        assert node.counters["states_taken"] == 0
        env.reset(seed=0)  # the client holds the node now: only its session may send a state
        assert client.send_state(good)["time_s"] == SAVED_AT  # signed with its session key
        intruder = node_start.encode_request(client.client_id, b"\0" * proto.KEY_SIZE, good)
        with pytest.raises(Refused, match="only the holder's session"):
            node_start.take_state(node, intruder)
        with pytest.raises(Refused, match="only the holder's session"):
            node_start.take_state(node, node_start.encode_request(0, None, good))
        with pytest.raises(BadRequest, match="more than the limit"):
            node_start.take_state(node, b"\0" * (proto.MAX_STATE_BYTES + 1))
        with pytest.raises(BadRequest, match="JSON part claims"):
            node_start.take_state(node, b"\xff\xff\xff\xff{}")
        assert node.counters["states_taken"] == 1
