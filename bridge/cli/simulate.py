"""Open-loop episodes of an experiment: ``fmu-bridge simulate`` and the quick checks of ``check``.

Policies here are fixed rules (no learning): ``zero`` (no change: 0 on every FMU input and the
FMU's start value on every tunable parameter), ``start`` (the model as exported: every input at its
declared start value, parameters untouched), ``random`` (seeded samples of the action space) and
``constant:V`` (the physical value V on every action input).

A physical value reaches the FMU exactly (an :class:`~bridge.task.core.ExactAction` carries it past
the action mapping); a value outside an input's bounds, or between the levels of a discrete
action, is changed to the nearest allowed value with one warning naming the value, the bound and the
variable. A model without actions takes only ``zero`` and ``start`` (nothing is applied).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from bridge.errors import ConfigError
from bridge.task.core import Task
from bridge.task.fixed import is_fixed_policy, physical_action, start_values, unknown_policy, zero_values

Policy = Callable[[Any], Any]
_log = logging.getLogger(__name__)


@dataclass
class EpisodeResult:
    episode: int
    scenario: str
    steps: int
    episode_return: float
    reason: str | None
    time_s: float
    final_outputs: dict[str, float] = field(default_factory=dict)


def make_policy(spec: str, task: Task, seed: int | None) -> Policy:
    """A fixed policy from its name: ``zero``, ``start``, ``random`` or ``constant:V``."""
    if not is_fixed_policy(spec):
        raise ConfigError(unknown_policy(spec))
    if not task.action_inputs:
        if spec not in ("zero", "start"):
            raise ConfigError(
                f"--policy {spec}: the experiment has no actions (actions.inputs is empty), so there is "
                "nothing to apply it to; leave --policy out (zero: nothing applied), or add an FMU input "
                "or tunable parameter to actions.inputs"
            )
        nothing = task.action_for_inputs([])
        return lambda obs: nothing
    if spec in ("zero", "start"):
        values = zero_values(task) if spec == "zero" else start_values(task)
        action = physical_action(task, values, f"--policy {spec}")
        return lambda obs: action
    if spec == "random":
        space = task.action_space
        space.seed(seed)
        return lambda obs: space.sample()
    try:
        value = float(spec.partition(":")[2])
    except ValueError:
        raise ConfigError(f"--policy {spec!r}: expected constant:NUMBER, e.g. constant:2.5") from None
    if not math.isfinite(value):
        raise ConfigError(f"--policy {spec!r}: expected a finite number, e.g. constant:2.5")
    action = physical_action(task, [value] * len(task.action_inputs), f"--policy {spec}")
    return lambda obs: action


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
