"""The ``training`` section of an experiment (RL Zoo-like), with command-line overrides."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, format_validation_error
from bridge.net.transport import ZenohOptions

Algo = Literal["PPO", "SAC", "TD3", "A2C", "DQN"]


class RemoteSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    nodes: str = "*"
    connect: list[str] = []
    listen: list[str] = []
    zenoh_config: str | None = None
    zenoh_mode: str | None = None
    timeout_s: float = 5.0
    replace_dead: bool = False

    def options(self) -> ZenohOptions:
        from pathlib import Path

        from bridge.net.transport import session_mode

        config = Path(self.zenoh_config) if self.zenoh_config else None
        listen, connect = tuple(self.listen), tuple(self.connect)
        return ZenohOptions(
            config_file=config,
            mode=session_mode(self.zenoh_mode, listen, connect, config),
            listen=listen,
            connect=connect,
        )


class TrainingSettings(BaseModel):
    """``training:`` in the experiment file; every key may be overridden on the command line."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    algo: Algo = "PPO"
    timesteps: int = Field(default=100_000, ge=1)
    n_envs: int = Field(default=4, ge=1)
    vec: Literal["dummy", "subproc", "remote", "batch"] = "dummy"
    seed: int = 0
    hyperparams: dict[str, Any] = {}
    normalize: bool | dict[str, Any] = False
    checkpoint_every: int = Field(default=50_000, ge=1)
    eval_every: int = Field(default=10_000, ge=1)
    eval_episodes: int = Field(default=5, ge=1)
    eval_scenarios: list[str] | None = None
    residual: dict[str, Any] | None = None
    remote: RemoteSettings = RemoteSettings()

    @classmethod
    def from_experiment(cls, experiment: Experiment, overrides: dict[str, Any]) -> TrainingSettings:
        data = {**experiment.training, **{k: v for k, v in overrides.items() if v is not None}}
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise ConfigError(
                format_validation_error(exc, experiment.source).replace("  ", "  training.")
            ) from None

    def evaluation_scenarios(self, experiment: Experiment) -> list[str]:
        return list(self.eval_scenarios or experiment.schedule.evaluation)

    def normalize_kwargs(self, eval_env: bool = False) -> dict[str, Any]:
        kwargs = dict(self.normalize) if isinstance(self.normalize, dict) else {}
        if eval_env:
            kwargs.pop("norm_reward", None)
            kwargs.pop("training", None)
        return kwargs


def linear_schedule_kwargs(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """RL Zoo's ``lin_0.001`` strings become linear schedules; ``policy_kwargs.activation_fn``
    names become torch classes."""
    out = dict(hyperparams)
    for key in ("learning_rate", "clip_range"):
        value = out.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            start = float(value[4:])
            out[key] = lambda progress, start=start: progress * start
    policy_kwargs = dict(out.get("policy_kwargs", {}))
    if isinstance(policy_kwargs.get("activation_fn"), str):
        import torch

        name = policy_kwargs["activation_fn"]
        activations = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "elu": torch.nn.ELU}
        if name.lower() not in activations:
            raise ConfigError(
                f"training.hyperparams.policy_kwargs.activation_fn: {name!r}; use {list(activations)}"
            )
        policy_kwargs["activation_fn"] = activations[name.lower()]
    if policy_kwargs:
        out["policy_kwargs"] = policy_kwargs
    return out


def package_versions() -> dict[str, str]:
    found = {}
    for name in ("fmu-bridge", "fmpy", "gymnasium", "stable-baselines3", "torch", "numpy", "eclipse-zenoh"):
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            continue
    return found
