"""RLlib's own env runner over BatchVectorEnv: with NEXT_STEP every recorded episode starts in its
drawn initial state, ends in the FMU's terminal state and has every step the FMU took; a SAME_STEP
env, which RLlib would silently corrupt, is refused when RLlib builds it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

pytest.importorskip("ray.rllib")

from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

from bridge.env.batch import BatchVectorEnv
from bridge.env.rllib import ppo_config
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment

K = 4
STATE = ("x", "x_dot", "theta", "theta_dot")  # cartpole_balance observes these outputs, raw


def cartpole() -> Any:
    return load_experiment(example_experiment("cartpole_balance"))


def episode_faults(episodes: list[Any], output_names: list[str]) -> list[str]:
    """What is wrong with each finished episode, read as RLlib recorded it."""
    observed = [output_names.index(name) for name in STATE]
    faults = []
    for n, episode in enumerate(episodes):
        if not episode.is_done:
            continue
        obs, infos = episode.get_observations(), episode.get_infos()
        end = infos[-1].get("final_info", infos[-1])  # SAME_STEP nests the end info
        if "outputs" not in end:
            faults.append(f"episode {n}: its last info is not the end of an FMU episode: {sorted(end)}")
            continue
        terminal = np.asarray(end["outputs"], dtype=np.float32)[observed]
        if not np.array_equal(obs[-1], terminal):
            faults.append(f"episode {n}: terminal obs {obs[-1]} is not the FMU's terminal state {terminal}")
        if len(episode) != int(end["step"]):
            faults.append(f"episode {n}: {len(episode)} steps recorded, the FMU took {end['step']}")
        drawn = infos[0].get("drawn")
        if drawn is None:
            faults.append(f"episode {n}: its first info is not a reset's: {sorted(infos[0])}")
        else:  # the first obs is the drawn initial state (parameters x0, ...)
            start = np.asarray([drawn[f"{name}0"] for name in STATE], dtype=np.float32)
            if not np.array_equal(obs[0], start):
                faults.append(f"episode {n}: first obs {obs[0]} is not its initial state {start}")
    return faults


def sample(config: Any, timesteps: int = 600) -> list[Any]:
    runner = SingleAgentEnvRunner(config=config.debugging(seed=1))
    try:
        return list(runner.sample(num_timesteps=timesteps, random_actions=True))
    finally:
        runner.stop()


@pytest.mark.parametrize("k", [K, 1])  # a batch of one runs its own (scalar Task) path
def test_rllib_env_runner_over_next_step_batch_env_records_whole_episodes(k: int) -> None:
    exp = cartpole()
    episodes = sample(ppo_config(exp, envs_per_runner=k))
    names = BatchVectorEnv(exp, 1).engine.task.output_names
    finished = [e for e in episodes if e.is_done]
    assert len(finished) >= 3 * k, f"only {len(finished)} episodes ended: sample longer"
    assert episode_faults(episodes, names) == []


def test_same_step_built_by_rllib_is_refused_with_or_without_the_guard() -> None:
    """A SAME_STEP batch env would have RLlib record the next episode's reset state as every
    terminal observation and drop every later first step, silently: built by RLlib it is refused,
    under a stock config (``register_env`` over ``BatchVectorEnv``, its default mode) too."""
    from ray.tune.registry import register_env

    exp = cartpole()
    register_env("test_user_batch_env", lambda cfg: BatchVectorEnv(exp, int(cfg["num_envs"])))
    stock = (
        PPOConfig()
        .environment(env="test_user_batch_env")
        .env_runners(num_envs_per_env_runner=K, gym_env_vectorize_mode="vector_entry_point")
    )
    with pytest.raises(ConfigError, match=r"NEXT_STEP autoreset.*'SameStep'.*autoreset_mode=AutoresetMode"):
        sample(stock)
    with pytest.raises(ConfigError, match=r"NEXT_STEP autoreset.*'SameStep'"):
        sample(ppo_config(exp, envs_per_runner=K, autoreset_mode="SameStep"))
    BatchVectorEnv(exp, 2).close()  # built outside RLlib, SAME_STEP stays the default (SB3's)
