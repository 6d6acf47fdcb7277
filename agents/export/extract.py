"""A run directory as what every export needs: normalisation, network layers, action mapping, names.

The deterministic action of each algorithm (as ``model.predict(deterministic=True)`` computes it):
PPO/A2C the Gaussian mean (or the argmax of the logits), clipped to the action space; SAC the tanh
of the mean, unscaled; TD3 the actor's (tanh) output, unscaled; DQN the argmax of the Q-values.
A run of ``train --engine rllib`` is read from its ``rllib_policy.npz`` (``agents.export.rllib_policy``):
``unsquash`` (the mean mapped from [-1, 1] onto the Box, clipped) or ``argmax``, as RLlib acts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from agents.export.ops import FloatArray, Op, network_ops
from bridge.errors import ConfigError

Head = Literal["clip", "squash", "unscale", "unsquash", "argmax"]
_HEADS: dict[str, Head] = {"PPO": "clip", "A2C": "clip", "SAC": "squash", "TD3": "unscale", "DQN": "argmax"}


@dataclass
class PolicyParts:
    """Everything between the Task's observation vector and the plant's input values.

    Attributes:
        obs_mean, obs_std, obs_clip: VecNormalize ``clip((obs - mean) / std, -clip, clip)`` with
            ``std = sqrt(var + epsilon)``; ``obs_mean is None`` when the run has no statistics.
        ops: the network's deterministic path (float32 weights as float64 arrays).
        head: how the network output becomes the agent's action.
        low, high: the Box action space (continuous heads).
        centre, half: continuous action ``a`` -> input values ``centre + half * clip(a, -1, 1)``.
        table: discrete action ``i`` -> input values ``table[i]``.
    """

    algo: str
    observation_names: list[str]
    input_names: list[str]
    units: dict[str, str]
    ops: list[Op]
    head: Head
    obs_mean: FloatArray | None = None
    obs_std: FloatArray | None = None
    obs_clip: float = float("inf")
    low: FloatArray = field(default_factory=lambda: np.zeros(0))
    high: FloatArray = field(default_factory=lambda: np.zeros(0))
    centre: FloatArray = field(default_factory=lambda: np.zeros(0))
    half: FloatArray = field(default_factory=lambda: np.zeros(0))
    table: FloatArray | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def discrete(self) -> bool:
        return self.head == "argmax"


def actor_modules(model: Any, algo: str) -> list[Any]:
    """The torch modules of the deterministic path, in order (before the head)."""
    if algo in ("PPO", "A2C"):
        policy = model.policy
        if getattr(policy, "use_sde", False) or getattr(policy, "squash_output", False):
            raise ConfigError(f"{algo} with gSDE (use_sde) cannot be exported; train without use_sde")
        extractor = getattr(policy, "pi_features_extractor", policy.features_extractor)
        return [extractor, policy.mlp_extractor.policy_net, policy.action_net]
    if algo == "SAC":
        if getattr(model.actor, "use_sde", False):
            raise ConfigError("SAC with gSDE (use_sde) cannot be exported; train without use_sde")
        return [model.actor.features_extractor, model.actor.latent_pi, model.actor.mu]
    if algo == "TD3":
        return [model.actor.features_extractor, model.actor.mu]
    if algo == "DQN":
        return [model.q_net.features_extractor, model.q_net.q_net]
    raise ConfigError(f"algorithm {algo!r} cannot be exported; supported: {sorted(_HEADS)}")


def load_parts(run: Path) -> tuple[PolicyParts, Any]:
    """Read a run directory (or its model .zip): the parts and the loaded SB3 model (``None`` for
    a run trained with ``--engine rllib``: its network is in the parts' ops)."""
    from agents.deploy import deployment_experiment, model_info_for
    from agents.policies import Sb3Policy, rllib_run
    from bridge.experiment.validate import check_experiment, timing
    from bridge.task.core import Task

    run_dir = run if run.is_dir() else run.parent
    if rllib_run(run_dir):
        return _rllib_parts(run_dir), None
    policy = Sb3Policy(run)
    if policy.residual:
        raise ConfigError(
            f"{run} is a residual policy (a baseline plus a learned correction): export the baseline "
            "and the correction together is not supported; deploy it with `agent run --runtime torch`"
        )
    algo = str(policy.run.get("algo") or type(policy.model).__name__)
    experiment, _ = deployment_experiment(run, None)
    info = model_info_for(experiment, run_dir, None)
    check_experiment(experiment, info)
    task = Task(experiment, info.variables, timing(experiment, info))
    ops = network_ops(actor_modules(policy.model, algo))
    parts = PolicyParts(
        algo=algo,
        observation_names=observation_names(task),
        input_names=list(task.action_inputs),
        units={n: info.variables[n].unit or "" for n in (*task.action_inputs, *task.output_names)},
        ops=ops,
        head=_HEADS[algo],
    )
    _set_normalisation(parts, policy)
    _set_actions(parts, task, policy.model)
    parts.metadata = _metadata(parts, policy.name, experiment)
    return parts, policy.model


def _rllib_parts(run_dir: Path) -> PolicyParts:
    from agents.deploy import deployment_experiment, model_info_for
    from agents.export.rllib_policy import read_policy
    from bridge.experiment.validate import check_experiment, timing
    from bridge.task.core import Task

    algo, ops, head = read_policy(run_dir)
    experiment, _ = deployment_experiment(run_dir, None)
    info = model_info_for(experiment, run_dir, None)
    check_experiment(experiment, info)
    task = Task(experiment, info.variables, timing(experiment, info))
    parts = PolicyParts(
        algo=algo,
        observation_names=observation_names(task),
        input_names=list(task.action_inputs),
        units={n: info.variables[n].unit or "" for n in (*task.action_inputs, *task.output_names)},
        ops=ops,
        head="argmax" if head == "argmax" else "unsquash",
    )
    _set_actions(parts, task, task)
    parts.metadata = _metadata(parts, run_dir.name, experiment) | {"engine": "rllib"}
    return parts


def observation_names(task: Any) -> list[str]:
    """Names of the observation elements; with history ``name@t-k`` (k samples ago), oldest first."""
    names = list(task.observer.names)
    history = task.experiment.observations.history
    if history == 1:
        return names
    return [f"{n}@t-{history - 1 - k}" for k in range(history) for n in names]


def _set_normalisation(parts: PolicyParts, policy: Any) -> None:
    rms = policy._obs_rms
    if rms is None:
        return
    parts.obs_mean = np.asarray(rms.mean, dtype=np.float64)
    parts.obs_std = np.sqrt(np.asarray(rms.var, dtype=np.float64) + policy._eps)
    parts.obs_clip = float(policy._clip)


def _set_actions(parts: PolicyParts, task: Any, model: Any) -> None:
    """Action space (of ``model``: the SB3 model, or the Task itself) and its map to input values."""
    import gymnasium as gym

    rng = np.random.default_rng(0)
    n = len(task.action_inputs)
    space = model.action_space
    if isinstance(space, gym.spaces.Box):
        if parts.head == "argmax":
            raise ConfigError(f"{parts.algo} acts on discrete spaces only, but the run's space is {space}")
        parts.low, parts.high = space.low.astype(np.float64), space.high.astype(np.float64)
        zero = np.asarray(task.action_to_inputs(np.zeros(n), 0, rng)[:n], dtype=np.float64)
        one = np.asarray(task.action_to_inputs(np.ones(n), 0, rng)[:n], dtype=np.float64)
        parts.centre, parts.half = zero, one - zero
    elif isinstance(space, gym.spaces.Discrete):
        parts.head = "argmax"
        rows = [task.action_to_inputs(i, 0, rng)[:n] for i in range(int(space.n))]
        parts.table = np.asarray(rows, dtype=np.float64)
    else:
        raise ConfigError(f"action space {space} cannot be exported; supported: Box and Discrete")


def _metadata(parts: PolicyParts, name: str, experiment: Any) -> dict[str, Any]:
    from agents.settings import package_versions

    return {
        "experiment": experiment.name,
        "experiment_version": experiment.version,
        "algo": parts.algo,
        "observation_names": parts.observation_names,
        "action_inputs": parts.input_names,
        "units": parts.units,
        "action_kind": "discrete" if parts.discrete else "continuous",
        "observation_processing": "caller (the Task: selection, scaling, errors, history)",
        "packages": package_versions(),
        "run": name,
    }
