"""RLlib over fmu-bridge's batch env (needs the ``ray`` extra: ``pip install "fmu-bridge[ray]"``).

RLlib's env runner reads a gymnasium vector env by NEXT_STEP rules (an episode's last observation is
the one returned with ``terminated``/``truncated``; the sub-env resets on the following step) and
never reads ``metadata["autoreset_mode"]``. Given a SAME_STEP vector env it records the next
episode's reset state as every terminal observation and drops every later episode's first step,
without an error. So:

- :class:`BatchEnvCreator` builds a :class:`BatchVectorEnv` of ``num_envs`` instances in NEXT_STEP
  (RLlib passes ``num_envs`` with ``gym_env_vectorize_mode="vector_entry_point"``);
- :class:`NextStepOnly`, an RLlib callback, refuses any env runner env that declares another
  autoreset mode (:func:`check_next_step`), so a SAME_STEP env fails at creation, not silently;
- :func:`algo_config` (PPO or SAC; :func:`ppo_config` for PPO) puts the two together.
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gymnasium.vector import AutoresetMode
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.algorithms.sac import SACConfig
from ray.rllib.callbacks.callbacks import RLlibCallback

from bridge.env.batch import BatchVectorEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, as_experiment


def check_next_step(env: Any) -> None:
    """Raise :class:`ConfigError` unless ``env`` declares NEXT_STEP autoreset (gymnasium's default
    where ``metadata`` has no ``autoreset_mode``), the only mode RLlib's env runner reads right."""
    declared = getattr(env, "metadata", {}).get("autoreset_mode", AutoresetMode.NEXT_STEP)
    try:
        mode = AutoresetMode(declared)
    except ValueError:
        mode = None
    if mode is not AutoresetMode.NEXT_STEP:
        name = type(getattr(env, "unwrapped", env)).__name__
        raise ConfigError(
            f"RLlib's env runner reads vector envs by NEXT_STEP autoreset rules, but this {name} declares "
            f"autoreset_mode {getattr(declared, 'value', declared)!r}: its episodes would end in the next "
            "episode's reset state and lose their first step. Build it with "
            "autoreset_mode=AutoresetMode.NEXT_STEP (BatchEnvCreator does for BatchVectorEnv)"
        )


class NextStepOnly(RLlibCallback):  # type: ignore[misc]
    """RLlib callback: refuse an env runner's env that does not declare NEXT_STEP autoreset."""

    def on_environment_created(self, *, env: Any, **kwargs: Any) -> None:
        check_next_step(env)


class BatchEnvCreator:
    """RLlib env creator: a NEXT_STEP :class:`BatchVectorEnv` of ``env_config["num_envs"]`` instances.

    Args:
        experiment: an :class:`Experiment` or the path of an experiment YAML file.
        kwargs: passed on to :class:`BatchVectorEnv` (``threads``, ``native``, ``on_error``,
            ``autoreset_mode``; the last only to show that RLlib refuses anything but NEXT_STEP).
    """

    def __init__(self, experiment: Experiment | str | Path, **kwargs: Any) -> None:
        self.experiment = as_experiment(experiment)
        self.kwargs = {"autoreset_mode": AutoresetMode.NEXT_STEP, **kwargs}

    def __call__(self, env_config: Mapping[str, Any]) -> BatchVectorEnv:
        if "num_envs" not in env_config:
            raise ConfigError(
                "BatchEnvCreator builds a vector env: configure RLlib with "
                "env_runners(gym_env_vectorize_mode='vector_entry_point', num_envs_per_env_runner=K)"
            )
        return BatchVectorEnv(self.experiment, int(env_config["num_envs"]), **self.kwargs)


ALGORITHMS = {"PPO": PPOConfig, "SAC": SACConfig}


def algo_config(
    algo: str,
    experiment: Experiment | str | Path,
    *,
    envs_per_runner: int,
    num_env_runners: int = 0,
    **env_kwargs: Any,
) -> Any:
    """An RLlib config of ``algo`` (PPO or SAC) whose env runners each host a NEXT_STEP batch env of
    ``envs_per_runner`` FMU instances, with :class:`NextStepOnly` installed (training settings are
    left to the caller)."""
    from ray.tune.registry import register_env

    if algo not in ALGORITHMS:
        raise ConfigError(f"RLlib algorithm {algo!r}: supported here are {sorted(ALGORITHMS)}")
    creator = BatchEnvCreator(experiment, **env_kwargs)
    name = f"fmu_bridge_batch_{uuid.uuid4().hex[:12]}"  # the Algorithm takes a registered name
    register_env(name, creator)
    return (
        ALGORITHMS[algo]()  # type: ignore[no-untyped-call]
        .environment(env=name)
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=envs_per_runner,
            gym_env_vectorize_mode="vector_entry_point",
        )
        .callbacks(NextStepOnly)
    )


def ppo_config(
    experiment: Experiment | str | Path,
    *,
    envs_per_runner: int,
    num_env_runners: int = 0,
    **env_kwargs: Any,
) -> Any:
    """:func:`algo_config` for PPO."""
    return algo_config(
        "PPO", experiment, envs_per_runner=envs_per_runner, num_env_runners=num_env_runners, **env_kwargs
    )
