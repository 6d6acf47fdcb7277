"""Components served by nodes: ``NodeComponent`` (the client) and the experiment a node serves.

A component with ``node: NAME`` runs in an :class:`bridge.net.node.FmuNode` of that name, started
by ``fmu-bridge system serve SYSTEM.yaml``. A node serves one FMU with the inputs and outputs its
experiment names, so ``system serve`` gives it a generated single-FMU experiment
(:func:`component_experiment`): the component's FMU, parameters and step size, one sample per
macro step, actions = the component's connected inputs and the task inputs on it (in that
order), observations = every output of the FMU and then any other variable of it the task
reads. Both sides read the same system file, so they agree on the names; the client maps its
bound inputs and outputs onto the node's lists by name and says so when they do not fit. The
serving machine reads only the FMUs of the components it serves.

A node answers in lockstep: ``send`` publishes the stamped inputs at once and ``receive``
waits for the matching outputs, so Jacobi components in several nodes step in parallel. For
fixed-point iteration the master saves and restores components: a node component marks its
next action SAVE_STATE or RESTORE_STATE (``bridge.net.node_state``) and rolls its own step
stamp back, so a repeated macro step costs no round trip more than the first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from bridge.errors import FMU_LOG_HEADER, ConfigError, StepError
from bridge.experiment.config import Experiment, parse_experiment
from bridge.fmu.vocab import ModelInfo, info_from_summary
from bridge.net import protocol as proto
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant
from bridge.plant.system.description import Component, SystemDescription, from_experiment, split_name

if TYPE_CHECKING:
    from bridge.net.node import FmuNode
    from bridge.net.transport import ZenohOptions

SERVE_HINT = "`fmu-bridge system serve SYSTEM.yaml` starts the component nodes"


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
    ins: list[str] = [c.target.variable for c in system.connections if c.target.component == name]
    ins += [e.variable for e in _ends(task.inputs, system, "actions") if e.component == name]
    outs = [v.name for v in info.by_causality("output")]
    outs += [c.source.variable for c in system.connections if c.source.component == name]
    outs += [e.variable for e in _ends(task.outputs, system, "observations") if e.component == name]
    return list(dict.fromkeys(ins)), list(dict.fromkeys(outs))


def served_info(system: SystemDescription, name: str) -> ModelInfo:
    """The model of component ``name``, served on this machine: its FMU must be here."""
    from bridge.fmu import read_model_info

    _check_here(system, name)
    return read_model_info(system.components[name].fmu)


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
    from bridge.experiment.validate import with_elements
    from bridge.plant.system.plant import system_info, system_timing
    from bridge.task.expr import expression_names

    own = system_info(experiment, system, {name: info}, system_timing(experiment, system)).variables
    others = system.components.keys() - {name}
    spelled = [n.partition(".") for n in expression_names(experiment.reward.expression or "")]
    return set(with_elements(own)) | {"".join(p) for p in spelled if p[1] and p[0] in others}


def _ends(names: Sequence[str], system: SystemDescription, key: str) -> list[Any]:
    return [split_name(n, system.components, key, system.where) for n in names]


def component_experiment(experiment: Experiment, system: SystemDescription, name: str) -> Experiment:
    """The single-FMU experiment the node of component ``name`` serves: one sample per macro step.
    The reward is a placeholder; a node only applies raw input values. The action bounds are the
    FMU's declared min/max, else wide (values between components are physical, and the node
    refuses values outside the bounds it serves)."""
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
    data = {
        "name": f"{experiment.name}.{name}",
        "description": f"component {name} of the system {experiment.name}",
        "model": {
            "fmu": str(component.fmu),
            "interface": component.interface,
            "step_size": t.step_size_s / n,
            "sampling_time": t.step_size_s,
            "start_time": t.start_time_s,
            "episode_duration": experiment.model.episode_duration,
            "parameters": dict(component.parameters),
        },
        "actions": {"inputs": ins, **_input_bounds(info, ins)},
        "observations": {"outputs": outs, "scale": "none"},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=experiment.source)


_WIDE = 1e15  # no declared bound: anything a connected component can produce


def _input_bounds(info: ModelInfo, inputs: Sequence[str]) -> dict[str, dict[str, float]]:
    variables = info.variables
    low = {n: -_WIDE if variables[n].min is None else variables[n].min for n in inputs}
    high = {n: _WIDE if variables[n].max is None else variables[n].max for n in inputs}
    return {"low": low, "high": high}  # type: ignore[dict-item]


def serve_components(
    experiment: Experiment,
    names: Sequence[str] = (),
    *,
    options: ZenohOptions | None = None,
    prefix: str = "fmu_bridge",
    session: Any = None,
) -> list[FmuNode]:
    """Start an :class:`FmuNode` for each component with ``node:`` (or those in ``names``), in this
    process; the caller closes them. Each node opens its own session unless ``session`` is given.
    Only the served components' FMUs need be on this machine."""
    served = served_experiments(experiment, names)
    return start_nodes(served, options=options, prefix=prefix, session=session)


def served_experiments(experiment: Experiment, names: Sequence[str] = ()) -> dict[str, Experiment]:
    """The experiment of each component to serve here (those with ``node:``, or those in
    ``names``) by node name, all checked before any node starts. Reads only their FMUs."""
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
    return {system.components[n].node or n: component_experiment(experiment, system, n) for n in chosen}


def start_nodes(
    experiments: Mapping[str, Experiment],
    *,
    options: ZenohOptions | None = None,
    prefix: str = "fmu_bridge",
    session: Any = None,
) -> list[FmuNode]:
    """An :class:`FmuNode` per ``{node name: experiment}``; none is left running if one fails."""
    from bridge.net.node import FmuNode

    nodes: list[FmuNode] = []
    try:
        for node, exp in experiments.items():
            nodes.append(FmuNode(exp, name=node, options=options, prefix=prefix, session=session))
    except BaseException:
        for started in nodes:
            started.close()
        raise
    return nodes


class NodeComponent(Plant):
    """One component of a system served by a node; a sample is one macro step.

    Args:
        component: the component (its ``node`` names the node).
        macro_step_s: the system's macro step; the node must serve samples of this length.
        start_time_s: the system's start time.
        session: an open Zenoh session (owned by the caller).
        prefix: the key prefix the node serves under.
        timeout_s: how long a reset or step may take before :class:`StepTimeout`.
    """

    def __init__(
        self,
        component: Component,
        macro_step_s: float,
        start_time_s: float,
        *,
        session: Any,
        prefix: str,
        timeout_s: float,
        where: str = "",
    ) -> None:
        from bridge.net.channel import ChannelClient

        self.component = component
        node = component.node or component.name
        self.name = f"component {component.name!r} (node {node!r})"
        self.client = ChannelClient(session, node, prefix=prefix, timeout_s=timeout_s)
        d = self.client.description
        self.info = info_from_summary(d["model"])
        self.timing = _check_timing(self.name, d, macro_step_s, start_time_s, where)
        self._node_inputs: list[str] = list(d["input_names"])
        self._node_outputs: list[str] = list(d["output_names"])
        self._u = np.zeros(len(self._node_inputs))
        self._in_index: list[int] = []
        self._out_index: list[int] = []
        self._time_s = start_time_s
        self._where = where
        self._flags = 0  # SAVE_STATE or RESTORE_STATE for the next action

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        self._in_index = self._positions(self.input_names, self._node_inputs, "inputs")
        self._out_index = self._positions(self.output_names, self._node_outputs, "outputs")
        # the usual case (both sides bound alike): values pass through without reordering
        self._all_inputs = self._in_index == list(range(len(self._node_inputs)))
        self._all_outputs = self._out_index == list(range(len(self._node_outputs)))

    def _positions(self, names: Sequence[str], served: list[str], what: str) -> list[int]:
        missing = [n for n in names if n not in served]
        if missing:
            raise ConfigError(
                f"{self.name}: the node serves {what} {served}, not {missing}; restart the node with "
                f"this experiment file ({SERVE_HINT}){self._where}"
            )
        return [served.index(n) for n in names]

    @property
    def time_s(self) -> float:
        return self._time_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated, self._flags = 0, False, 0
        merged = {**self.component.parameters, **values}
        for i, name in enumerate(self._node_inputs):  # inputs nobody binds: their start values
            self._u[i] = float(merged.get(name, _start(self.info.variables[name].start)))
        self._write(inputs)
        frame = self.client.reset(self, merged, self._u.tolist())
        self._time_s = frame.sim_time_ns / 1e9
        return frame.values[self._out_index]

    def _write(self, inputs: Sequence[float] | None) -> None:
        if inputs is not None:
            self._u[self._in_index] = inputs

    def send(self, inputs: Sequence[float] | None) -> None:
        flags, self._flags = self._flags, 0
        if self._all_inputs and inputs is not None:
            self._u[:] = inputs
            self.client.send_action(self, self.episode, self.sample + 1, inputs, flags)
            return
        self._write(inputs)
        self.client.send_action(self, self.episode, self.sample + 1, self._u.tolist(), flags)

    def receive(self) -> FloatArray:
        frame = self.client.wait(self)
        self._time_s = frame.sim_time_ns / 1e9
        self.sample += 1
        if frame.kind == proto.ERROR:  # the FMU's own words and log
            detail, _, log = frame.message.partition(FMU_LOG_HEADER)
            raise self.failure(
                StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, step=self.sample, log=log.split("\n  ")
            )
        self.terminated = frame.terminated
        return frame.values if self._all_outputs else frame.values[self._out_index]

    # -- saved states (rollback): carried by the next action -----------------------------------------
    @property
    def can_save(self) -> bool:
        """Whether the node can save and restore its FMU state (its ``info`` says so)."""
        return bool(self.client.description.get("can_save_state", False))

    @property
    def save_refusal(self) -> str:
        """Why the node cannot save its state ("" if it can)."""
        if self.can_save:
            return ""
        return str(self.client.description.get("save_state_refusal") or "the node is too old to save states")

    def save(self) -> tuple[int, bool, float, FloatArray]:
        """The node saves its state with the next action (SAVE_STATE); this keeps the step stamp."""
        self._flags = proto.SAVE_STATE
        return self.sample, self.terminated, self._time_s, self._u.copy()

    def restore(self, saved: tuple[int, bool, float, FloatArray]) -> None:
        """The next action goes back to the saved state first (RESTORE_STATE), stamped as then."""
        self.sample, self.terminated, self._time_s, u = saved
        self._u[:] = u
        self._flags = proto.RESTORE_STATE

    def discard(self, saved: tuple[int, bool, float, FloatArray]) -> None:
        """Nothing to free here: the node keeps one state, replaced by the next save."""
        self._flags = 0

    def provenance(self) -> dict[str, str]:
        d = self.client.description
        return {"fmu": str(self.component.fmu), "fmu_sha256": d.get("fmu_sha256", ""), "node": d["node"]}

    def close(self) -> None:
        client = getattr(self, "client", None)
        if client is not None:
            client.close()
            self.client = None  # type: ignore[assignment]


def _check_timing(name: str, d: Mapping[str, Any], macro_s: float, t0: float, where: str) -> Any:
    from bridge.experiment.validate import Timing

    if not math.isclose(d["sampling_time_s"], macro_s, rel_tol=1e-12) or d["start_time_s"] != t0:
        raise ConfigError(
            f"{name}: the node steps {d['sampling_time_s']} s from t0 = {d['start_time_s']} s; the system "
            f"has macro step {macro_s} s from {t0} s: start the node from this system file ({SERVE_HINT})"
            f"{where}"
        )
    return Timing(d["step_size_s"], d["steps_per_sample"], macro_s, t0)


def _start(value: Any) -> float:
    try:
        return float(value) if value is not None else 0.0
    except (TypeError, ValueError):
        return 0.0


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
        return NodeComponent(
            component,
            step_size_s,
            start_time_s,
            session=self._open(),
            prefix=self.prefix,
            timeout_s=self.timeout_s,
            where=where,
        )

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
            self._infos[node] = query_info(self._open(), proto.Keys(self.prefix, node), self.timeout_s)
        return self._infos[node]

    def close(self) -> None:
        if self._own and self._session is not None:
            self._session.close()
        self._session = None
