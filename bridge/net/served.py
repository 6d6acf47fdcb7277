"""``Served``: what a node serves, described by its plant's inputs and outputs.

A node applies input values, steps, and publishes output values; it needs no task. What it must
know is small and fixed at start: the input and output names in wire order, the values a reset
may set, each input's allowed range, the nominal values a real-time node starts from, and the
timing. :class:`Served` holds exactly that, built

- from an experiment (:func:`served_by`): its signal names and request rules, read from the
  file's sections; no reward is compiled and no callable imported, so a node starts on an
  experiment whose reward code lives only on the trainer's machine;
- for a component of a system (``bridge.net.system_node``): from the system's connections and
  the component's FMU, with no experiment of its own.

Only numeric variables travel (the wire carries float64 values): a String output of a
component is not served, and the client is told so by name if it asks for one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, with_elements
from bridge.fmu.vocab import ModelInfo, Variable

_LARGEST = 1.7976931348623157e308  # nothing declared: the finite doubles (NaN, inf refused)


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


def served_by(experiment: Experiment, info: ModelInfo, timing: Timing) -> Served:
    """What a node serves for ``experiment`` over the model ``info``: the task's signal names and
    the experiment's request rules, without compiling or importing the task's code."""
    from bridge.task.core import task_signal_names

    variables = with_elements(info.variables)
    names = task_signal_names(experiment, variables)
    low, high = input_ranges(experiment, variables, names.inputs)
    model = experiment.model
    return Served(
        title=experiment.name,
        version=experiment.version,
        input_names=tuple(names.inputs),
        output_names=tuple(names.outputs),
        settable=declared_names(experiment, variables),
        low=tuple(low),
        high=tuple(high),
        timing=timing,
        nominal={**model.parameters, **model.start_values},
        ranges={} if experiment.hooks.episode else experiment_ranges(experiment),
    )


def declared_names(experiment: Experiment, variables: Mapping[str, Variable]) -> frozenset[str]:
    """The values a reset may set: those the experiment declares (parameters, start values,
    scenarios, randomisation), or any settable variable when a ``hooks.episode`` chooses them."""
    if experiment.hooks.episode:
        return frozenset(n for n, v in variables.items() if v.settable_at_init)
    model = experiment.model
    names = set(model.parameters) | set(model.start_values)
    randomizations = [experiment.randomization]
    for scenario in experiment.scenarios.values():
        names |= set(scenario.parameters) | set(scenario.start_values)
        randomizations.append(scenario.randomization)
    for r in randomizations:
        names |= set(r.parameters) | set(r.start_values)
    return frozenset(n for n in names if n in variables)


def input_ranges(
    experiment: Experiment, variables: Mapping[str, Variable], names: Sequence[str]
) -> tuple[list[float], list[float]]:
    """Per input: the hull of the FMU's min/max and the experiment's bounds, levels and table."""
    actions = experiment.actions
    low, high = [], []
    for name in names:
        var = variables[name]
        listed = list(actions.levels.get(name, []))
        if actions.table and name in actions.inputs:
            column = actions.inputs.index(name)
            listed += [row[column] for row in actions.table if column < len(row)]
        lows = [v for v in (var.min, actions.low.get(name)) if v is not None] + listed
        highs = [v for v in (var.max, actions.high.get(name)) if v is not None] + listed
        low.append(float(min(lows)) if lows else -_LARGEST)
        high.append(float(max(highs)) if highs else _LARGEST)
    return low, high


def element_start(info: ModelInfo, name: str) -> float:
    """The start value of a variable, or of one element ``u[2]`` of an FMI 3.0 array (0 without one)."""
    var, index = info.element(name)
    start = var.start
    if index is not None:
        start = start[index] if isinstance(start, list | tuple) and index < len(start) else None
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
        low.append(-_LARGEST if var.min is None else float(var.min))
        high.append(_LARGEST if var.max is None else float(var.max))
    return low, high


def experiment_ranges(experiment: Experiment) -> dict[str, tuple[float, float]]:
    """Per numeric name: the hull of what the experiment can set; a name any value may reach
    (a normal or lognormal draw, a non-numeric value) has no entry."""
    seen: dict[str, list[float]] = {}
    open_ended: set[str] = set()

    def fixed(values: Mapping[str, Any]) -> None:
        for name, value in values.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                seen.setdefault(name, []).append(float(value))
            else:
                open_ended.add(name)

    def drawn(distributions: Mapping[str, Any]) -> None:
        for name, dist in distributions.items():
            support = {"uniform": dist.uniform, "choice": dist.choice}.get(dist.kind)
            if dist.kind == "truncnormal":
                support = dist.truncnormal[2:]
            if support is None:
                open_ended.add(name)
            else:
                seen.setdefault(name, []).extend(float(v) for v in support)

    model = experiment.model
    fixed({**model.parameters, **model.start_values})
    randomizations = [experiment.randomization]
    for scenario in experiment.scenarios.values():
        fixed({**scenario.parameters, **scenario.start_values})
        randomizations.append(scenario.randomization)
    for r in randomizations:
        drawn({**r.parameters, **r.start_values})
    return {name: (min(v), max(v)) for name, v in seen.items() if name not in open_ended}
