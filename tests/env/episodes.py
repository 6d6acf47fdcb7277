"""Episodes read from a vector env the way a NEXT_STEP consumer (gymnasium's default, RLlib's env
runner) reads them, and replayed in one single FmuEnv as the reference."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import Experiment


@dataclass
class Episode:
    obs: list[np.ndarray] = field(default_factory=list)  # first (reset) obs, then one per step
    actions: list[Any] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    end: dict[str, Any] | None = None  # the env's end info (reason, step, outputs) when it ended


def episodes_next_step(env: Any, *, seed: int, steps: int, rng: np.random.Generator) -> list[list[Episode]]:
    """Step ``env`` with random discrete actions; split each sub-env's stream into episodes by NEXT_STEP
    rules: an obs with terminated or truncated is the episode's last, the next step's obs is the next
    episode's first (its action ignored)."""
    n = env.num_envs
    obs, _ = env.reset(seed=seed)
    current = [Episode(obs=[obs[i]]) for i in range(n)]
    per_env: list[list[Episode]] = [[c] for c in current]
    ended = np.zeros(n, dtype=bool)
    for _ in range(steps):
        actions = rng.integers(0, 2, size=n)
        obs, reward, terminated, truncated, info = env.step(actions)
        for i in range(n):
            if ended[i]:
                current[i] = Episode(obs=[obs[i]])
                per_env[i].append(current[i])
                continue
            current[i].obs.append(obs[i])
            current[i].actions.append(int(actions[i]))
            current[i].rewards.append(float(reward[i]))
            if terminated[i] or truncated[i]:
                current[i].end = {key: info[key][i] for key in ("step", "outputs", "reason") if key in info}
        ended = terminated | truncated
    return per_env


def replay_in_fmu_env(exp: Experiment, *, seed: int, episodes: list[Episode]) -> None:
    """Replay a sub-env's episodes in one FmuEnv (reset with ``seed``, then unseeded): every
    observation, reward and end must be the same."""
    env = FmuEnv(exp)
    try:
        for k, episode in enumerate(episodes):
            obs, _ = env.reset(seed=seed if k == 0 else None)
            np.testing.assert_array_equal(episode.obs[0], obs, err_msg=f"episode {k}: first observation")
            done = False
            for t, action in enumerate(episode.actions):
                assert not done, f"episode {k} goes on after its end at step {t}"
                obs, reward, terminated, truncated, _ = env.step(action)
                np.testing.assert_array_equal(episode.obs[t + 1], obs, err_msg=f"episode {k}, step {t + 1}")
                assert episode.rewards[t] == reward
                done = terminated or truncated
            assert done == (episode.end is not None), f"episode {k}: ended here, not in the FmuEnv"
    finally:
        env.close()
