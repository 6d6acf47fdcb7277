"""The ``training`` section of an experiment (RL Zoo-like), with command-line overrides."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, format_validation_error
from bridge.experiment.sections import NormalizeSection, RemoteSection, TrainingSection
from bridge.net.transport import ZenohOptions


class RemoteSettings(RemoteSection):
    """``training.remote``, with the Zenoh options it gives."""

    def options(self) -> ZenohOptions:
        from bridge.net.transport import session_mode

        config = Path(self.zenoh_config) if self.zenoh_config else None
        listen, connect = tuple(self.listen), tuple(self.connect)
        return ZenohOptions(
            config_file=config,
            mode=session_mode(self.zenoh_mode, listen, connect, config),
            listen=listen,
            connect=connect,
        )


class TrainingSettings(TrainingSection):
    """``training:`` in the experiment file, with the command-line overrides applied."""

    remote: RemoteSettings = RemoteSettings()

    @classmethod
    def from_experiment(cls, experiment: Experiment, overrides: dict[str, Any]) -> TrainingSettings:
        given = experiment.training.model_dump(exclude_unset=True)
        data = {**given, **{k: v for k, v in overrides.items() if v is not None}}
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise ConfigError(format_validation_error(exc, experiment.source, "training.")) from None

    def evaluation_scenarios(self, experiment: Experiment) -> list[str]:
        return list(self.eval_scenarios or experiment.schedule.evaluation)

    def normalize_kwargs(self, eval_env: bool = False) -> dict[str, Any]:
        """VecNormalize keyword arguments given in ``training.normalize`` (SB3's defaults otherwise)."""
        if not isinstance(self.normalize, NormalizeSection):
            return {}
        kwargs = self.normalize.model_dump(exclude_unset=True)
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
