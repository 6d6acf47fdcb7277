"""A node built from an experiment: the plant its ``model`` section describes, serving the
signal names its task reads and drives, under the request rules its sections give.

No reward is compiled and no callable imported (:func:`bridge.task.core.task_signal_names` reads
names only), so a node starts on an experiment whose reward code lives only on the trainer's
machine.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.validate import Timing, check_experiment, resolve_fmu, with_elements
from bridge.fmu import read_model_info
from bridge.fmu.vocab import ModelInfo, Variable
from bridge.net.served import LARGEST, Served
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.spec import PlantSpec
from bridge.task.core import task_signal_names

if TYPE_CHECKING:
    from bridge.net.node import FmuNode


def experiment_node(experiment: Experiment | str | Path, **node: Any) -> FmuNode:
    """An :class:`~bridge.net.node.FmuNode` serving the experiment's model (``node``: its keyword
    arguments: ``name``, ``mode``, ``options``, ``isolate``, ...). The experiment is checked
    against its FMU first, as an env over it checks it."""
    from bridge.net.node import FmuNode

    spec, served = experiment_served(as_experiment(experiment))
    return FmuNode(spec, served, **node)


def experiment_served(experiment: Experiment) -> tuple[PlantSpec, Served]:
    """The plant a node of ``experiment`` runs and what it serves, the experiment checked."""
    declared = read_model_info(resolve_fmu(experiment))
    info = check_experiment(experiment, declared)  # sized by model.structural_parameters
    spec = experiment_plant_spec(experiment, declared)
    return spec, served_by(experiment, info, spec.timing)


def served_by(experiment: Experiment, info: ModelInfo, timing: Timing) -> Served:
    """What a node serves for ``experiment`` over the model ``info``: the task's signal names and
    the experiment's request rules, without compiling or importing the task's code."""
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
        episode_duration_s=model.episode_duration,
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
        low.append(float(min(lows)) if lows else -LARGEST)
        high.append(float(max(highs)) if highs else LARGEST)
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
