"""Several agents in one system: the PettingZoo ParallelEnv over a SystemPlant."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant

pettingzoo = pytest.importorskip("pettingzoo", reason="pettingzoo is not installed (pip install pettingzoo)")

from bridge.env.multi_agent import SystemParallelEnv  # noqa: E402 (after the skip)

EXAMPLE = Path(__file__).parents[2] / "examples" / "motor_load_agents.yaml"


def example(tmp_path: Path, **agents: Any) -> Any:
    data = yaml.safe_load(EXAMPLE.read_text())
    for name, changes in agents.items():
        data["system"]["agents"][name].update(changes)
    return parse_experiment(data, source=tmp_path / "agents.yaml")


def test_the_parallel_env_passes_pettingzoos_api_test() -> None:
    from pettingzoo.test import parallel_api_test

    env = SystemParallelEnv(EXAMPLE)
    try:
        parallel_api_test(env, num_cycles=60)
    finally:
        env.close()


def test_each_agent_drives_its_inputs_and_gets_its_own_observations_and_reward(tmp_path: Path) -> None:
    """The same actions given to the system plant directly: the agents' slices of its outputs."""
    rng = np.random.default_rng(3)
    actions = [{"drive": rng.uniform(-1, 1, 1), "assist": rng.uniform(-1, 1, 1)} for _ in range(10)]
    env = SystemParallelEnv(EXAMPLE)
    try:
        env.reset(seed=0)
        steps = [env.step(a) for a in actions]
    finally:
        env.close()
    names = ["load.omega", "motor.omega", "motor.current"]
    with SystemPlant(example(tmp_path)) as plant:
        plant.bind(["motor.voltage", "load.tau_ext"], names)
        plant.reset({}, [0.0, 0.0])
        for a, (obs, rewards, terminated, truncated, _) in zip(actions, steps):
            voltage, tau = 12.0 * (a["drive"][0] + 1.0), -0.5 + 0.5 * (a["assist"][0] + 1.0)
            omega_load, omega_motor, current = plant.step([voltage, tau])
            np.testing.assert_allclose(obs["drive"], [omega_load, omega_motor], rtol=1e-6)
            np.testing.assert_allclose(obs["assist"], [current, omega_load], rtol=1e-6)
            assert rewards["drive"] == pytest.approx(-abs(omega_load - 8.0) / 8.0, rel=1e-12)
            assert rewards["assist"] == pytest.approx(-abs(current) / 10.0, rel=1e-12)
            assert not any(terminated.values()) and not any(truncated.values())


def test_an_episode_ends_for_every_agent_at_its_duration() -> None:
    env = SystemParallelEnv(EXAMPLE)
    try:
        env.reset(seed=0)
        samples = 0
        while env.agents:
            *_, truncated, _ = env.step({n: env.action_space(n).sample() for n in env.agents})
            samples += 1
        assert samples == 50 and truncated == {"drive": True, "assist": True}  # 1 s of 20 ms samples
    finally:
        env.close()


def test_an_input_driven_by_two_agents_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"\['motor.voltage'\] driven by more than one agent"):
        SystemParallelEnv(example(tmp_path, assist={"inputs": ["motor.voltage"]}))


def test_an_input_without_bounds_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"system.agents.assist: 'load.tau_ext' needs finite bounds"):
        SystemParallelEnv(example(tmp_path, assist={"low": {}, "high": {}}))


def test_a_bad_agent_reward_names_its_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"system.agents.drive.reward"):
        SystemParallelEnv(example(tmp_path, drive={"reward": {"terms": [{"bogus": 1.0}]}}))


@pytest.mark.slow
def test_two_agents_trained_together_improve_on_their_untrained_return(tmp_path: Path) -> None:
    """The README recipe, short: PPO for each agent in turn; the same numbers on every run. The
    evaluation episodes recorded per agent hold the returns it reports (read back by our reader)."""
    pytest.importorskip("stable_baselines3")
    from agents.multi_agent import train_agents
    from bridge.recording.reader import read_recording

    result = train_agents(EXAMPLE, timesteps=1024, rounds=1, seed=0, record=tmp_path)
    assert all(result.improved().values()), result
    gains = {n: result.trained[n] - result.untrained[n] for n in result.untrained}
    assert gains["drive"] > 5.0 and gains["assist"] > 2.0, result  # measured: 17.1 and 5.7
    assert result.recording is not None and result.recording.parent == tmp_path
    ends = [e for e in read_recording(result.recording).events if e.get("event") == "episode_end"]
    assert [e["returns"] for e in ends] == [result.untrained, result.trained]


def test_an_agent_name_that_is_no_identifier_is_refused(tmp_path: Path) -> None:
    """An agent's name becomes a topic segment of its recording and its policy's file name."""
    data = yaml.safe_load(EXAMPLE.read_text())
    data["system"]["agents"]["a/b"] = data["system"]["agents"].pop("drive")
    with pytest.raises(ConfigError, match=r"agent names are identifiers .*'a/b'"):
        parse_experiment(data, source=tmp_path / "agents.yaml")
