"""Recordings of several agents in one system: each agent's observations, actions and rewards on
its own topics, read back by an independent reader (mcap + mcap_ros2) and equal to what the
PettingZoo env returned; the file is read by our reader and replayed in Rerun per agent."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.recording import meta
from bridge.recording.agents_recorder import RecordAgents, record_agents, topic
from bridge.recording.reader import read_recording
from tests.recording.test_system_recording import mcap_messages

pytest.importorskip("pettingzoo", reason="pettingzoo is not installed (pip install pettingzoo)")

from bridge.env.multi_agent import SystemParallelEnv

EXAMPLE = Path(__file__).parents[2] / "examples" / "motor_load_agents.yaml"
AGENTS = ("drive", "assist")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """Two episodes (the first whole, the second ended by close()), and what the env returned at
    every step."""
    folder = tmp_path_factory.mktemp("agents_recording")
    env = record_agents(SystemParallelEnv(EXAMPLE), folder, run_name="two-agents", agent="sine", seed=5)
    rng = np.random.default_rng(1)
    seen: list[dict[str, Any]] = []
    for episode, seed in enumerate((5, 6)):
        observations, _ = env.reset(seed=seed)
        seen.append({"episode": episode, "observations": observations, "time_s": env.env.plant.time_s})
        while env.agents:
            actions = {n: rng.uniform(-1, 1, 1).astype(np.float32) for n in env.agents}
            observations, rewards, *_ = env.step(actions)
            applied = {n: v.copy() for n, v in env.env.applied_inputs.items()}
            seen.append(
                {
                    "episode": episode,
                    "actions": actions,
                    "applied": applied,
                    "observations": observations,
                    "rewards": rewards,
                    "time_s": env.env.plant.time_s,
                }
            )
            if episode == 1 and len(seen) > 60:
                break  # the second episode ends with close()
    env.close()
    assert env.path == folder / "two-agents.mcap" and env.path.is_file()
    return env.path, seen


def stamp(message: Any) -> int:
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def test_each_agent_has_its_observations_actions_and_rewards_on_its_own_topics(recorded: Any) -> None:
    path, seen = recorded
    found = mcap_messages(path)
    steps = [s for s in seen if "rewards" in s]
    for agent in AGENTS:
        observed = found[topic(agent, "observations")]
        assert len(observed) == len(seen)
        for (_, message), sample in zip(observed, seen):
            assert stamp(message) == round(sample["time_s"] * 1e9)
            np.testing.assert_array_equal(np.float32(message.position), sample["observations"][agent])
        actions, raw = found[topic(agent, "actions")], found[topic(agent, "agent_action")]
        rewards = found[topic(agent, "reward")]
        assert len(actions) == len(raw) == len(rewards) == len(steps)
        for (_, a), (_, r), (_, reward), step in zip(actions, raw, rewards, steps):
            assert list(a.position) == step["applied"][agent].tolist()
            np.testing.assert_array_equal(np.float32(r.position), step["actions"][agent])
            assert reward.data == step["rewards"][agent]
    drive_names = list(found[topic("drive", "observations")][0][1].name)
    assert drive_names == ["load.omega", "motor.omega"]
    assert list(found[topic("assist", "actions")][0][1].name) == ["load.tau_ext"]
    rewards = {a: [m.data for _, m in found[topic(a, "reward")]] for a in AGENTS}
    assert rewards["drive"] != rewards["assist"]  # each agent its own reward
    assert len(found[meta.component_topic("motor")]) == len(seen)


def test_episode_events_carry_each_agents_return(recorded: Any) -> None:
    path, seen = recorded
    found = mcap_messages(path)
    events = [json.loads(m.data) for _, m in found[meta.EVENTS]]
    ends = [e for e in events if e["event"] == "episode_end"]
    assert [e["reason"] for e in ends] == ["time", "closed"]
    for end in ends:
        steps = [s for s in seen if "rewards" in s and s["episode"] == end["episode"]]
        assert end["steps"] == len(steps)
        for agent in AGENTS:
            assert end["returns"][agent] == pytest.approx(sum(s["rewards"][agent] for s in steps), rel=1e-12)
    assert [e["seed"] for e in events if e["event"] == "episode_start"] == [5, 6]


def test_our_reader_and_the_rerun_replay_show_each_agent(recorded: Any, tmp_path: Path) -> None:
    rr_chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk is not installed")
    from bridge.recording.replay import replay

    path, _ = recorded
    recording = read_recording(path)
    assert recording.complete and [e.index for e in recording.episodes] == [0, 1]
    assert recording.metadata["fmu_bridge"]["agents"] == json.dumps(list(AGENTS), separators=(",", ":"))
    target = replay(path, save=tmp_path / "agents.rrd")
    assert target is not None
    entities = set()
    for chunk in rr_chunk.RrdReader(target).stream().collect().stream():
        if not chunk.is_static:
            entities.add(chunk.entity_path)
    for agent in AGENTS:
        assert f"/agents/{agent}/reward" in entities
    for name in ("load.omega", "motor.omega"):
        assert f"/agents/drive/observations/{name}" in entities
    assert "/agents/assist/actions/load.tau_ext" in entities
    assert "/agents/assist/agent_action/load.tau_ext" in entities


def test_only_a_parallel_env_over_a_system_with_agents_is_recorded(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"system\.agents"):
        RecordAgents(object(), tmp_path / "x.mcap")
    assert not list(tmp_path.iterdir())


def test_the_recording_env_passes_pettingzoos_api_test(tmp_path: Path) -> None:
    from pettingzoo.test import parallel_api_test

    env = RecordAgents(SystemParallelEnv(EXAMPLE), tmp_path / "api.mcap")
    try:
        parallel_api_test(env, num_cycles=60)
    finally:
        env.close()
    recording = read_recording(tmp_path / "api.mcap")
    assert recording.complete and len(recording.series[topic("drive", "reward")]) > 0
