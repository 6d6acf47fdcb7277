"""fmu-bridge: FMUs as Gymnasium environments, Zenoh nodes and ROS 2 citizens."""

from __future__ import annotations

from bridge.errors import (
    BridgeError,
    ConfigError,
    DependencyMissing,
    FmuError,
    FmuLoadError,
    PlantDied,
    PlantError,
    StepError,
    StepTimeout,
    TransportError,
    VariableError,
)

__version__ = "0.1.0"

__all__ = [
    "BridgeError",
    "ConfigError",
    "DependencyMissing",
    "FmuError",
    "FmuLoadError",
    "PlantDied",
    "PlantError",
    "StepError",
    "StepTimeout",
    "TransportError",
    "VariableError",
    "__version__",
]
