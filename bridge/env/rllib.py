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
- :class:`NodeEnvCreator` builds a NEXT_STEP :class:`NodeVectorEnv` instead: each env runner
  drives ``num_envs`` nodes it leases from a pool (``claim``), a dead node replaced by a spare;
- :func:`register` registers an experiment's env under a stable name, ``fmu_bridge/<name>``
  (``fmu_bridge/<name>-<version>`` for a version other than v0), for any RLlib or Ray Tune config
  (``PPOConfig().environment("fmu_bridge/cartpole-balance")``); registered again in a fresh process,
  it lets ``Algorithm.from_checkpoint`` restore a checkpoint that names it;
- :func:`algo_config` (PPO or SAC; :func:`ppo_config` for PPO) puts them together.

A SAME_STEP ``BatchVectorEnv`` or ``NodeVectorEnv`` built by RLlib (a stock config over
``register_env(..., lambda cfg: BatchVectorEnv(...))``) is refused at construction
(``bridge.env.autoreset.refuse_same_step_under_rllib``), callback or not.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gymnasium.vector import AutoresetMode
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.algorithms.sac import SACConfig
from ray.rllib.callbacks.callbacks import RLlibCallback

from bridge.env.autoreset import same_step_refusal
from bridge.env.batch import BatchVectorEnv
from bridge.env.fmu_env import FmuEnv
from bridge.env.node_vector import NodeVectorEnv
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
        raise ConfigError(same_step_refusal(name, declared))


class NextStepOnly(RLlibCallback):  # type: ignore[misc]
    """RLlib callback: refuse an env runner's env that does not declare NEXT_STEP autoreset."""

    def on_environment_created(self, *, env: Any, **kwargs: Any) -> None:
        check_next_step(env)


class BatchEnvCreator:
    """RLlib env creator: a NEXT_STEP :class:`BatchVectorEnv` of ``env_config["num_envs"]`` instances
    (``gym_env_vectorize_mode="vector_entry_point"``), or, under RLlib's default vectorisation
    (gymnasium's ``SyncVectorEnv``, NEXT_STEP), one :class:`FmuEnv` per call.

    Args:
        experiment: an :class:`Experiment` or the path of an experiment YAML file.
        kwargs: passed on to :class:`BatchVectorEnv` (``threads``, ``native``, ``on_error``,
            ``autoreset_mode``; the last only to show that RLlib refuses anything but NEXT_STEP).
    """

    def __init__(self, experiment: Experiment | str | Path, **kwargs: Any) -> None:
        self.experiment = as_experiment(experiment)
        self.kwargs = {"autoreset_mode": AutoresetMode.NEXT_STEP, **kwargs}

    def __call__(self, env_config: Mapping[str, Any]) -> BatchVectorEnv | FmuEnv:
        if "num_envs" not in env_config:  # RLlib's default (sync) vectorisation: one env each,
            return FmuEnv(self.experiment)  # in gymnasium's SyncVectorEnv (NEXT_STEP)
        return BatchVectorEnv(self.experiment, int(env_config["num_envs"]), **self.kwargs)


class NodeEnvCreator:
    """RLlib env creator: a NEXT_STEP :class:`NodeVectorEnv` of ``env_config["num_envs"]`` nodes.

    Each env runner opens its own Zenoh session (``options``) and leases the nodes it drives
    (``claim=True``): runners drawing on one pool never share a node, and a runner that dies
    (its session with it) frees its nodes for its replacement. A node that dies or hangs is
    replaced by a spare matching ``nodes`` (``replace_dead=True``, waiting up to
    ``replace_wait_s``), its episode truncated.

    Args:
        experiment: the experiment the nodes serve.
        nodes: a glob pattern (``"worker-*"``) or node names.
        remote: passed on to :class:`NodeVectorEnv` (``options``, ``prefix``, ``timeout_s``,
            ``replace_wait_s``, ``discovery_timeout_s``, ...).
    """

    def __init__(self, experiment: Experiment | str | Path, nodes: str | list[str], **remote: Any) -> None:
        self.experiment = as_experiment(experiment)
        self.nodes = nodes
        self.remote = {"claim": True, "replace_dead": True, "replace_wait_s": 60.0, **remote}

    def __call__(self, env_config: Mapping[str, Any]) -> NodeVectorEnv:
        if "num_envs" not in env_config:
            raise ConfigError(
                "NodeEnvCreator builds a vector env: configure RLlib with "
                "env_runners(gym_env_vectorize_mode='vector_entry_point', num_envs_per_env_runner=K)"
            )
        return NodeVectorEnv(
            self.experiment,
            self.nodes,
            n_envs=int(env_config["num_envs"]),
            autoreset_mode=AutoresetMode.NEXT_STEP,
            **self.remote,
        )


ALGORITHMS = {"PPO": PPOConfig, "SAC": SACConfig}
PREFIX = "fmu_bridge/"


def env_name(experiment: Experiment | str | Path) -> str:
    """The stable name :func:`register` gives the experiment's env: ``fmu_bridge/<name>``, or
    ``fmu_bridge/<name>-<version>`` for a version other than v0 (``name``: the file's ``name:``)."""
    exp = as_experiment(experiment)
    return f"{PREFIX}{exp.name}" + ("" if exp.version == "v0" else f"-{exp.version}")


def register(
    experiment: Experiment | str | Path, *, nodes: str | list[str] | None = None, **env_kwargs: Any
) -> str:
    """Register the experiment's env with Ray Tune's registry under :func:`env_name` and return
    that name: a NEXT_STEP batch env of ``num_envs_per_env_runner`` FMU instances per env runner
    (:class:`BatchEnvCreator`), or, ``nodes`` given, a NEXT_STEP vector env over that many leased
    nodes (:class:`NodeEnvCreator`); ``env_kwargs`` go to the creator. Configure RLlib with
    ``gym_env_vectorize_mode="vector_entry_point"`` (:func:`algo_config` does).

    Registration lives in the process (and its Ray cluster): a fresh process registers again
    before ``Algorithm.from_checkpoint`` (``agents.rllib_train.restore`` does both for a run).
    """
    from ray.tune.registry import register_env

    exp = as_experiment(experiment)
    creator: Any = (
        BatchEnvCreator(exp, **env_kwargs) if nodes is None else NodeEnvCreator(exp, nodes, **env_kwargs)
    )
    name = env_name(exp)
    register_env(name, creator)
    return name


def algo_config(
    algo: str,
    experiment: Experiment | str | Path,
    *,
    envs_per_runner: int,
    num_env_runners: int = 0,
    nodes: str | list[str] | None = None,
    **env_kwargs: Any,
) -> Any:
    """An RLlib config of ``algo`` (PPO or SAC) whose env runners each host a NEXT_STEP batch env of
    ``envs_per_runner`` FMU instances, or (``nodes`` given) drive ``envs_per_runner`` leased nodes
    (:class:`NodeEnvCreator`), with :class:`NextStepOnly` installed (training settings are left to
    the caller). ``env_kwargs`` go to the creator."""
    if algo not in ALGORITHMS:
        raise ConfigError(f"RLlib algorithm {algo!r}: supported here are {sorted(ALGORITHMS)}")
    name = register(experiment, nodes=nodes, **env_kwargs)
    return (
        ALGORITHMS[algo]()
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
