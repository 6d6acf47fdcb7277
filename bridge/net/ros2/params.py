"""An FMU's parameters as ROS parameters of its node (rclpy's parameter services on the rclpy backend,
``bridge.net.ros2.param_services`` on the zenoh backend), as fmi_adapter users know them.

Declared: the FMU's parameters (causality ``parameter``, variability ``fixed`` or ``tunable``)
that the experiment lets a reset set (principle 8: a reset sets only what the experiment declares),
each with the model description's range (``min``/``max``; an open end is the largest double) and
the value the next episode starts with (the experiment's, else the FMU's start value).

``ros2 param set /plant R 2.0`` between episodes (before the first ``~/reset``, or once an episode
has ended: terminated, or ``model.episode_duration`` reached in lockstep) is kept and applies at
the next ``~/reset``; inside an episode it is refused with the reason, and rclpy refuses a value
outside the declared range itself. Nothing here imports rclpy or Zenoh.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from bridge.fmu.vocab import ModelInfo

LARGEST = 1.7976931348623157e308
KINDS = {"Float64": float, "Float32": float, "Real": float, "Boolean": bool}


@dataclass(frozen=True)
class FmuParameter:
    """One FMU parameter offered as a ROS parameter of the same name."""

    name: str
    value: float | bool
    low: float
    high: float
    description: str


def fmu_parameters(
    info: ModelInfo, settable: Iterable[str], nominal: Mapping[str, Any]
) -> list[FmuParameter]:
    """The FMU parameters a reset may set, with their ranges and the value the next episode uses."""
    offered = []
    for name in sorted(settable):
        variable = info.variables.get(name)
        if variable is None or variable.causality != "parameter" or variable.type not in KINDS:
            continue
        if variable.variability not in ("fixed", "tunable"):
            continue
        kind = KINDS[variable.type]
        value = kind(nominal.get(name, variable.start))
        low = -LARGEST if variable.min is None else float(variable.min)
        high = LARGEST if variable.max is None else float(variable.max)
        text = variable.description or f"FMU parameter {name}"
        unit = f" [{variable.unit}]" if variable.unit else ""
        offered.append(FmuParameter(name, value, low, high, f"{text}{unit}; applies at the next ~/reset"))
    return offered
