"""Residual RL: the agent's action is added to a baseline controller's (a config switch).

The agent acts in [-1, 1]; its action times ``scale`` (physical units) is added to the
baseline's physical inputs, and the sum goes through the task's action mapping. Trained and
evaluated like any other agent; the run directory records the baseline so evaluation rebuilds it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from agents.policies import combine, residual_baseline
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.experiment.sections import ResidualSection
from bridge.task.core import Task


def residual_setup(experiment: Experiment, residual: ResidualSection) -> dict[str, Any]:
    """Resolve ``training.residual`` ({baseline: NAME, scale: S}) against ``evaluation.baselines``."""
    baselines = experiment.evaluation.baselines
    name = residual.baseline
    if name not in baselines:
        raise ConfigError(
            f"training.residual.baseline: {name!r} is not in evaluation.baselines "
            f"({sorted(baselines) or 'none defined'})"
        )
    if experiment.actions.type != "continuous":
        raise ConfigError("training.residual needs continuous actions (actions.type: continuous)")
    if baselines[name].type not in ("pid", "lqr", "mpc"):
        raise ConfigError(
            f"training.residual.baseline: {name!r} is a {baselines[name].type} baseline; "
            "use a pid, lqr or mpc"
        )
    return {"baseline": name, "config": baselines[name].settings(), "scale": residual.scale}


class ResidualWrapper(gym.Wrapper[Any, Any, Any, Any]):
    """Wraps an FmuEnv (or RemoteFmuEnv): the agent learns a correction on top of the baseline."""

    def __init__(self, env: gym.Env[Any, Any], residual: Mapping[str, Any]) -> None:
        super().__init__(env)
        self._residual = residual
        self._scale = float(residual["scale"])
        self._baseline = residual_baseline(residual)
        self._task: Task = env.unwrapped.task  # type: ignore[attr-defined]
        n = len(self._task.action_inputs)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._baseline.reset(self._task, None)
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        signals = self._task.controller_signals()
        return self.env.step(combine(self._task, self._baseline, signals, action, self._scale))
