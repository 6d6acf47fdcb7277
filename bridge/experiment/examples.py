"""The example experiments shipped with fmu-bridge, and their Gymnasium ids.

``gymnasium.make("fmu_bridge/CartPole-v0")`` works once ``bridge.env.fmu_env`` is imported (or use
``gymnasium.make("bridge.env.fmu_env:fmu_bridge/CartPole-v0")``, which imports it).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

from bridge.errors import ConfigError

# Gymnasium id -> (example file, env version)
GYM_IDS: dict[str, tuple[str, str]] = {
    "fmu_bridge/CartPole-v0": ("cartpole_balance", "v0"),
    "fmu_bridge/CartPole-v1": ("cartpole_balance", "v1"),
    "fmu_bridge/CartPoleContinuous-v0": ("cartpole_continuous", "v0"),
    "fmu_bridge/DCMotorTracking-v0": ("dcmotor_tracking", "v0"),
}


def examples_dir() -> Path:
    """``examples/`` of a source checkout, or its copy inside an installed wheel."""
    installed = Path(__file__).resolve().parents[1] / "_examples"
    if installed.is_dir():
        return installed
    return Path(__file__).resolve().parents[2] / "examples"


def example_names() -> list[str]:
    return sorted(p.stem for p in examples_dir().glob("*.yaml"))


def example_experiment(name: str) -> Path:
    """The path of the example experiment ``name`` (file stem, e.g. ``cartpole_balance``)."""
    path = examples_dir() / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"no example experiment {name!r}; examples: {example_names()}")
    return path


def register_envs() -> None:
    """Register the example envs with Gymnasium (idempotent)."""
    for env_id, (example, version) in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="bridge.env.fmu_env:FmuEnv",
                kwargs={"experiment": str(examples_dir() / f"{example}.yaml"), "version": version},
            )
