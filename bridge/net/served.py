"""``Served``: what a node serves, described by its plant's inputs and outputs.

A node applies input values, steps, and publishes output values; it needs no task. What it must
know is small and fixed at start: the input and output names in wire order, the values a reset
may set, each input's allowed range, the nominal values a real-time node starts from, the
timing, and how long an episode driven anonymously (ROS lockstep) lasts. :class:`Served` holds
exactly that. It is built above the network (``bridge.serving``):

- from an experiment (``bridge.serving.experiment.served_by``): the names its task reads and
  drives and its request rules, read from the file's sections;
- for a component of a system (``bridge.serving.system``): from the system's connections and
  the component's FMU, with no experiment of its own.

Only numeric variables travel (the wire carries float64 values): a String output of a
component is not served, and the client is told so by name if it asks for one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from bridge.experiment.validate import Timing
from bridge.fmu.vocab import ModelInfo, Variable

LARGEST = 1.7976931348623157e308  # nothing declared: the finite doubles (NaN, inf refused)


@dataclass(frozen=True)
class Served:
    """What one node serves. ``low``/``high`` bound each input; ``settable`` is what a reset may
    set; ``nominal`` the values a real-time node (or a ROS reset) starts an episode with."""

    title: str  # what ``info`` reports as the experiment (a component: ``system.component``)
    version: str
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    settable: frozenset[str]
    low: tuple[float, ...]
    high: tuple[float, ...]
    timing: Timing
    nominal: Mapping[str, Any] = field(default_factory=dict)
    # per numeric name a reset may set: the hull of what the experiment itself can give
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    # an episode whose actions come without a step stamp (ROS lockstep) ends after this long
    episode_duration_s: float = math.inf


def element_start(info: ModelInfo, name: str) -> float:
    """The start value of a variable, or of one element ``u[2]`` of an FMI 3.0 array (0 without one)."""
    var, index = info.element(name)
    start: Any = var.start if index is None else var.element_starts()[index]
    try:
        return float(start) if start is not None else 0.0
    except (TypeError, ValueError):
        return 0.0


def declared_ranges(
    variables: Mapping[str, Variable], names: Sequence[str]
) -> tuple[list[float], list[float]]:
    """Per input: the FMU's declared min/max, else the finite doubles."""
    low, high = [], []
    for name in names:
        var = variables[name]
        low.append(-LARGEST if var.min is None else float(var.min))
        high.append(LARGEST if var.max is None else float(var.max))
    return low, high
