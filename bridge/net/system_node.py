"""Components served by nodes: what a component's node serves, and the client's plants.

A component with ``node: NAME`` runs in an :class:`bridge.net.node.FmuNode` of that name, started
by ``fmu-bridge system serve SYSTEM.yaml``. What the node serves is read from the system, with
no experiment of its own (:func:`component_served`, a :class:`~bridge.net.served.Served`): the
inputs are the component's connected inputs and the task inputs on it (in that order), the
outputs every numeric output of the FMU (an FMI 3.0 array by its elements ``y[1,1]``, ``y[1,2]``,
...) and then any other variable of it the task reads (String and Binary outputs are not served:
the wire carries numbers), the range of an input is the FMU's declared min/max (an element
``u[2]``: its array's), a reset may set the component's parameters and what the system's experiment
sets on it, and a sample is one macro step. The node's plant comes from the plant factory like
every FMU plant, from the component's model only (:func:`component_model`: FMU, interface, step
size, parameters). Both sides read the same system file, so they agree on the names; the client
(:meth:`bridge.net.remote.RemotePlant.for_component`) maps its bound inputs and outputs onto the
node's lists by name and says so when they do not fit. The serving machine reads only the FMUs
of the components it serves.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.errors import ConfigError, TransportError
from bridge.experiment.config import Experiment, parse_experiment
from bridge.experiment.validate import Timing, with_elements
from bridge.fmu.vocab import ModelInfo, info_from_summary
from bridge.net import protocol as proto
from bridge.net.remote import SERVE_HINT, RemotePlant
from bridge.net.served import Served, declared_names, declared_ranges
from bridge.plant.base import Plant
from bridge.plant.system.description import Component, SystemDescription, from_experiment, split_name

if TYPE_CHECKING:
    from bridge.net.node import FmuNode
    from bridge.net.transport import ZenohOptions

__all__ = ["SERVE_HINT", "NodeComponents", "component_served", "serve_components", "start_nodes"]


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
    from bridge.task.core import task_signal_names

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
    from bridge.task.expr import expression_names

    own = system_info(experiment, system, {name: info}, system_timing(experiment, system)).variables
    others = system.components.keys() - {name}
    spelled = [n.partition(".") for n in expression_names(experiment.reward.expression or "")]
    return set(with_elements(own)) | {"".join(p) for p in spelled if p[1] and p[0] in others}


def _ends(names: Sequence[str], system: SystemDescription, key: str) -> list[Any]:
    return [split_name(n, system.components, key, system.where) for n in names]


@dataclass(frozen=True)
class ServedComponent:
    """A component's node: the model its plant runs (:func:`component_model`) and what it serves."""

    model: Experiment
    served: Served


def component_served(experiment: Experiment, system: SystemDescription, name: str) -> ServedComponent:
    """What the node of component ``name`` serves (see the module doc); reads its FMU only."""
    from bridge.plant.system.component import steps_per_macro
    from bridge.plant.system.plant import system_timing

    component = system.components[name]
    t = system_timing(experiment, system)
    n = steps_per_macro(component, t.step_size_s, None, system.where)
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
        timing=Timing(t.step_size_s / n, n, t.step_size_s, t.start_time_s),
        nominal=own_values,
    )
    return ServedComponent(component_model(experiment, system, name, served), served)


_WIDE = 1e15


def component_model(
    experiment: Experiment, system: SystemDescription, name: str, served: Served
) -> Experiment:
    """The component's model as the plant factory reads it: FMU, interface, step size, sampling
    time (the macro step), parameters, structural parameters and clock settings; its signal sections only name
    what ``served`` serves."""
    component = system.components[name]
    t = served.timing
    data = {
        "name": served.title,
        "description": f"component {name} of the system {experiment.name}",
        "model": {
            "fmu": str(component.fmu),
            "interface": component.interface,
            "step_size": t.step_size_s,
            "sampling_time": t.sampling_time_s,
            "start_time": t.start_time_s,
            "episode_duration": experiment.model.episode_duration,
            "parameters": dict(component.parameters),
            "structural_parameters": dict(component.structural_parameters),
            "clock_intervals": dict(component.clock_intervals),
            "clock_schedule": {k: list(v) for k, v in component.clock_schedule.items()},
            "start_values": dict(component.start_values),
            "reset_policy": (
                {"state_file": str(component.state_file)} if component.state_file else component.reset_policy
            ),
            "tolerance": component.tolerance,
            "solver": component.solver,
            "solver_substeps": component.solver_substeps,
        },
        "actions": {  # bounds the model's checks ask for; the node checks served.low/high itself
            "inputs": list(served.input_names),
            "low": {n: max(v, -_WIDE) for n, v in zip(served.input_names, served.low)},
            "high": {n: min(v, _WIDE) for n, v in zip(served.input_names, served.high)},
        },
        "observations": {"outputs": list(served.output_names), "scale": "none"},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=experiment.source)


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
    served = served_experiments(experiment, names)
    return start_nodes(
        served,
        options=options,
        prefix=prefix,
        session=session,
        isolate=isolate,
        step_timeout_s=step_timeout_s,
    )


def served_experiments(experiment: Experiment, names: Sequence[str] = ()) -> dict[str, ServedComponent]:
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
                    c.model,
                    name=node,
                    options=options,
                    prefix=prefix,
                    session=session,
                    served=c.served,
                    isolate=isolate,
                    step_timeout_s=step_timeout_s,
                )
            )
    except BaseException:
        for started in nodes:
            started.close()
        raise
    return nodes


class NodeComponents:
    """Builds the plants of a system's node components on one shared Zenoh session.

    Given to ``SystemPlant(remote=...)`` by the env, so that plants never import the network.

    Args:
        options: how to open the session (when ``session`` is None; opened on first use).
        session: an open session to share (owned by the caller).
        prefix: the key prefix the component nodes serve under.
        timeout_s: how long a reset or macro step may take before :class:`StepTimeout`.
    """

    def __init__(
        self,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = "fmu_bridge",
        timeout_s: float = 10.0,
    ) -> None:
        self._options, self._session, self._own = options, session, False
        self.prefix, self.timeout_s = prefix, timeout_s
        self._infos: dict[str, dict[str, Any]] = {}

    def _open(self) -> Any:
        if self._session is None:
            from bridge.net.transport import open_session

            self._session, self._own = open_session(self._options), True
        return self._session

    def __call__(self, component: Component, step_size_s: float, start_time_s: float, where: str) -> Plant:
        session = self._open()
        try:
            return RemotePlant.for_component(
                component,
                step_size_s,
                start_time_s,
                session=session,
                prefix=self.prefix,
                timeout_s=self.timeout_s,
                where=where,
            )
        except TransportError as exc:
            raise self._missing(component, exc) from exc

    def describe(self, component: Component) -> ModelInfo:
        """The component's model as its node reports it (the FMU need not be on this machine)."""
        return info_from_summary(self._info(component)["model"])

    def checksum(self, component: Component) -> str:
        """The SHA-256 of the FMU the component's node serves."""
        return str(self._info(component).get("fmu_sha256", ""))

    def _info(self, component: Component) -> dict[str, Any]:
        from bridge.net.remote import query_info

        node = component.node or component.name
        if node not in self._infos:
            session = self._open()
            try:
                self._infos[node] = query_info(session, proto.Keys(self.prefix, node), self.timeout_s)
            except TransportError as exc:
                raise self._missing(component, exc) from exc
        return self._infos[node]

    def _missing(self, component: Component, exc: TransportError) -> TransportError:
        """A component's node not found, said for a system: how to serve it, and the Zenoh mode."""
        if "no FMU node named" not in str(exc):
            return exc
        node, options = component.node or component.name, self._options
        hint = ""
        if options is not None and options.mode == "client" and len(options.connect) > 1:
            hint = (
                f"; this session runs in Zenoh client mode (--connect without --listen), which "
                f"reaches one router, not each of {list(options.connect)}: add --zenoh-mode peer to "
                f"connect to every endpoint"
            )
        elif options is not None and options.mode == "client":
            hint = f"; this session is a Zenoh client of {list(options.connect)}: the node must reach it too"
        return TransportError(
            f"system component {component.name!r}: no node {node!r} answers within {self.timeout_s:g} s "
            f"(prefix {self.prefix!r}); serve it with `fmu-bridge system serve EXPERIMENT --component "
            f"{component.name}` where its FMU is, and check the Zenoh endpoints{hint} "
            f"(`fmu-bridge nodes` lists the live ones)"
        )

    def close(self) -> None:
        if self._own and self._session is not None:
            self._session.close()
        self._session = None
