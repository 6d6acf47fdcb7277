"""Nodes for the components of a system: what each serves and the plant it runs.

A component with ``node: NAME`` runs in an :class:`bridge.net.node.FmuNode` of that name, started
by ``fmu-bridge system serve SYSTEM.yaml``. What the node serves is read from the system, with
no experiment of its own (:func:`component_served`, a :class:`~bridge.net.served.Served`): the
inputs are the component's connected inputs and the task inputs on it (in that order), the
outputs every numeric output of the FMU (an FMI 3.0 array by its elements ``y[1,1]``, ``y[1,2]``,
...) and then any other variable of it the task reads (String and Binary outputs are not served:
the wire carries numbers), the range of an input is the FMU's declared min/max (an element
``u[2]``: its array's), a reset may set the component's parameters and what the system's experiment
sets on it, and a sample is one macro step. The node's plant is the component's own description
(:func:`bridge.plant.system.component.component_plant_spec`), the one an in-process component is
built from: no experiment is invented for it. Both sides read the same system file, so they agree
on the names; the client (:class:`bridge.net.remote.RemotePlant`) maps its bound
inputs and outputs onto the node's lists by name and says so when they do not fit. The serving
machine reads only the FMUs of the components it serves.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import with_elements
from bridge.fmu.vocab import ModelInfo
from bridge.net.served import Served, declared_ranges
from bridge.plant.spec import PlantSpec
from bridge.plant.system.description import SystemDescription, from_experiment, split_name
from bridge.serving.experiment import declared_names
from bridge.task.core import task_signal_names
from bridge.task.expr import expression_names

if TYPE_CHECKING:
    from bridge.net.node import FmuNode
    from bridge.net.transport import ZenohOptions


def component_signals(
    experiment: Experiment, system: SystemDescription, name: str
) -> tuple[list[str], list[str]]:
    """The input and output names the node of component ``name`` serves (see the module doc).

    Reads this component's FMU only: the task's names on it are resolved against its variables
    (a typo there is the usual ConfigError); names on other components are taken as written (the
    client checks them against what their nodes or files describe)."""
    return _signals(experiment, system, name, served_info(system, name))


def _signals(
    experiment: Experiment, system: SystemDescription, name: str, info: ModelInfo
) -> tuple[list[str], list[str]]:
    task = task_signal_names(experiment, _known_names(experiment, system, name, info))
    # a whole array connected (to an array of its shape) by its elements, as the client connects it
    ins = [
        e
        for c in system.connections
        if c.target.component == name
        for e in _elements(info, c.target.variable)
    ]
    ins += [e.variable for e in _ends(task.inputs, system, "actions") if e.component == name]
    # every numeric output by element (an FMI 3.0 array: y[1,1], y[1,2], ...), as the client binds them
    outs = [e for v in info.by_causality("output") if v.is_numeric for e in v.element_names()]
    outs += [
        e
        for c in system.connections
        if c.source.component == name
        for e in _elements(info, c.source.variable)
    ]
    outs += [e.variable for e in _ends(task.outputs, system, "observations") if e.component == name]
    return list(dict.fromkeys(ins)), list(dict.fromkeys(outs))


def _elements(info: ModelInfo, name: str) -> list[str]:
    """``name``, or its elements where it names a whole FMI 3.0 array of this component."""
    var = info.variables.get(name)
    return var.element_names() if var is not None and var.dimensions else [name]


def served_info(system: SystemDescription, name: str) -> ModelInfo:
    """The model of component ``name``, served on this machine: its FMU must be here."""
    from bridge.fmu import read_model_info
    from bridge.plant.system.plant import sized_info

    _check_here(system, name)
    component = system.components[name]
    return sized_info(component, read_model_info(component.fmu))


def _check_here(system: SystemDescription, name: str) -> None:
    fmu = system.components[name].fmu
    if not fmu.is_file():
        raise ConfigError(
            f"system.components.{name}.fmu: {fmu} is not on this machine, which is to serve component "
            f"{name!r}; copy the FMU here, or serve here only the components whose FMUs are here "
            f"(`fmu-bridge system serve SYSTEM.yaml --component NAME`, repeatable){system.where}"
        )


def _known_names(experiment: Experiment, system: SystemDescription, name: str, info: ModelInfo) -> set[str]:
    """The variables of component ``name`` (``name.variable``, array elements included), and the
    names the reward expression spells on other components, whose FMUs need not be here."""
    from bridge.plant.system.plant import system_info, system_timing

    own = system_info(experiment, system, {name: info}, system_timing(experiment, system)).variables
    others = system.components.keys() - {name}
    spelled = [n.partition(".") for n in expression_names(experiment.reward.expression or "")]
    return set(with_elements(own)) | {"".join(p) for p in spelled if p[1] and p[0] in others}


def _ends(names: Sequence[str], system: SystemDescription, key: str) -> list[Any]:
    return [split_name(n, system.components, key, system.where) for n in names]


@dataclass(frozen=True)
class ServedComponent:
    """A component's node: the plant it runs (the component's own description) and what it serves."""

    plant: PlantSpec
    served: Served


def component_served(experiment: Experiment, system: SystemDescription, name: str) -> ServedComponent:
    """What the node of component ``name`` serves (see the module doc); reads its FMU only."""
    from bridge.plant.system.component import component_plant_spec
    from bridge.plant.system.plant import system_timing

    component = system.components[name]
    t = system_timing(experiment, system)
    spec = component_plant_spec(component, t.step_size_s, t.start_time_s, system.where)
    info = served_info(system, name)
    ins, outs = _signals(experiment, system, name, info)
    if not ins:
        raise ConfigError(
            f"system.components.{name}.node: a component served by a node needs at least one input "
            f"(connected or driven by the task); {name!r} has none: run it in this process{system.where}"
        )
    low, high = declared_ranges({n: info.element(n)[0] for n in ins}, ins)  # u[2]: u's declared range
    own_values = {**component.parameters, **component.start_values}  # the component's own settings
    prefix = f"{name}."  # what the system's experiment sets on this component, by its own names
    on_component = {prefix + k: v for k, v in info.variables.items()}
    settable = {n[len(prefix) :] for n in declared_names(experiment, on_component)}
    served = Served(
        title=f"{experiment.name}.{name}",
        version=experiment.version,
        input_names=tuple(ins),
        output_names=tuple(outs),
        settable=frozenset(settable | (set(own_values) & set(with_elements(info.variables)))),
        low=tuple(low),
        high=tuple(high),
        timing=spec.timing,
        nominal=own_values,
        episode_duration_s=experiment.model.episode_duration,
    )
    return ServedComponent(spec, served)


def serve_components(
    experiment: Experiment,
    names: Sequence[str] = (),
    *,
    options: ZenohOptions | None = None,
    prefix: str = "fmu_bridge",
    session: Any = None,
    isolate: bool = False,
    step_timeout_s: float = 10.0,
) -> list[FmuNode]:
    """Start an :class:`FmuNode` for each component with ``node:`` (or those in ``names``), in this
    process; the caller closes them. Each node opens its own session unless ``session`` is given.
    Only the served components' FMUs need be on this machine. ``isolate`` and ``step_timeout_s``
    are each node's (:class:`FmuNode`)."""
    served = served_components(experiment, names)
    return start_nodes(
        served,
        options=options,
        prefix=prefix,
        session=session,
        isolate=isolate,
        step_timeout_s=step_timeout_s,
    )


def served_components(experiment: Experiment, names: Sequence[str] = ()) -> dict[str, ServedComponent]:
    """What each component to serve here (those with ``node:``, or those in ``names``) serves,
    by node name, all checked before any node starts. Reads only their FMUs."""
    system = from_experiment(experiment, check_files=False)
    served = [n for n, c in system.components.items() if c.node is not None]
    chosen = list(names) or served
    unknown = [n for n in chosen if n not in served]
    if not served:
        raise ConfigError(
            f"system serve: no component of the system has node:; set system.components.NAME.node "
            f"to the node name that serves it{system.where}"
        )
    if unknown:
        raise ConfigError(
            f"system serve: {unknown} is not served by a node; components with node: {served}; "
            f"set system.components.NAME.node in the file{system.where}"
        )
    nodes = [system.components[n].node or n for n in chosen]
    twice = sorted({n for n in nodes if nodes.count(n) > 1})
    if twice:
        raise ConfigError(
            f"system serve: node names {twice} are given to more than one component of {chosen}; "
            f"give each served component its own system.components.NAME.node{system.where}"
        )
    for name in chosen:  # every missing FMU is named before anything else is checked
        _check_here(system, name)
    return {system.components[n].node or n: component_served(experiment, system, n) for n in chosen}


def start_nodes(
    components: Mapping[str, ServedComponent],
    *,
    options: ZenohOptions | None = None,
    prefix: str = "fmu_bridge",
    session: Any = None,
    isolate: bool = False,
    step_timeout_s: float = 10.0,
) -> list[FmuNode]:
    """An :class:`FmuNode` per ``{node name: component}``; none is left running if one fails.
    ``isolate`` runs each component's FMU in a child process of its own, and ``step_timeout_s``
    bounds its resets and steps, as ``fmu-bridge node --isolate --step-timeout`` does."""
    from bridge.net.node import FmuNode

    nodes: list[FmuNode] = []
    try:
        for node, c in components.items():
            nodes.append(
                FmuNode(
                    c.plant,
                    c.served,
                    name=node,
                    options=options,
                    prefix=prefix,
                    session=session,
                    isolate=isolate,
                    step_timeout_s=step_timeout_s,
                )
            )
    except BaseException:
        for started in nodes:
            started.close()
        raise
    return nodes
