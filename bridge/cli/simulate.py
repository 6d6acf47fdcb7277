"""Open-loop episodes of an experiment: ``fmu-bridge simulate`` and the quick checks of ``check``.

Policies here are fixed rules (no learning): ``zero`` (the action whose physical value is
nearest 0), ``random`` (seeded samples of the action space) and ``constant:V`` (the physical
value V on every action input).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from bridge.errors import ConfigError
from bridge.task.core import Task

Policy = Callable[[Any], Any]


@dataclass
class EpisodeResult:
    episode: int
    scenario: str
    steps: int
    episode_return: float
    reason: str | None
    time_s: float
    final_outputs: dict[str, float] = field(default_factory=dict)


def physical_action(task: Task, value: float) -> Any:
    """The action whose physical input value is nearest ``value`` on every action input."""
    return task.action_for_inputs([value] * len(task.action_inputs))


def make_policy(spec: str, task: Task, seed: int | None) -> Policy:
    """A fixed policy from its name: ``zero``, ``random`` or ``constant:V``."""
    if spec == "zero":
        action = physical_action(task, 0.0)
        return lambda obs: action
    if spec == "random":
        space = task.action_space
        space.seed(seed)
        return lambda obs: space.sample()
    if spec.startswith("constant:"):
        try:
            value = float(spec.partition(":")[2])
        except ValueError:
            raise ConfigError(f"--policy {spec!r}: expected constant:NUMBER, e.g. constant:2.5") from None
        action = physical_action(task, value)
        return lambda obs: action
    raise ConfigError(f"--policy {spec!r} is unknown; use zero, random or constant:VALUE")


def run_episodes(
    env: gym.Env[Any, Any],
    policy: Policy,
    episodes: int,
    *,
    seed: int | None = None,
    scenario: str | None = None,
    output_names: tuple[str, ...] = (),
) -> list[EpisodeResult]:
    """Run ``episodes`` episodes of ``policy`` and summarise each."""
    results = []
    for i in range(episodes):
        options = {"scenario": scenario} if scenario else None
        obs, info = env.reset(seed=seed if i == 0 else None, options=options)
        name, total, steps = info.get("scenario", "?"), 0.0, 0
        while True:
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            total += float(reward)
            steps += 1
            if terminated or truncated:
                break
        final = dict(zip(output_names, np.asarray(info["outputs"]).tolist()))
        results.append(EpisodeResult(i, name, steps, total, info.get("reason"), float(info["time_s"]), final))
    return results
