"""``SystemPlant``: a system of coupled FMUs behind the Plant interface.

Its variables are every component's, named ``component.variable``; the task drives the inputs no
connection drives and reads any output. A sample is ``steps_per_sample`` macro steps of the
master. Reset restarts the whole system (each component from its own state snapshot where it has
one), so the same seed replays the same trajectory.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bridge.errors import ConfigError, PlantDied, PlantError, StepError
from bridge.experiment.config import Experiment, sampling_ratio, scenario_inputs
from bridge.experiment.validate import Timing
from bridge.fmu.vocab import DefaultExperiment, ModelInfo
from bridge.plant.base import MODEL_FAILED_HINT, MODEL_HUNG, FloatArray, Plant
from bridge.plant.system.check import check_system, expand_arrays
from bridge.plant.system.description import (
    Component,
    Connection,
    Endpoint,
    SystemDescription,
    from_experiment,
    split_name,
)
from bridge.plant.system.graph import find_loop, gauss_seidel_order, has_feedthrough, init_order, loop_error
from bridge.plant.system.master import Link, Master
from bridge.plant.system.transform import Convert


class RemoteComponents(Protocol):
    """Builds the plant of a component served by a node (``bridge.net.system_node`` has one).

    Injected by whoever may use the network (the env), so that plants never import it."""

    def __call__(self, component: Component, step_size_s: float, start_time_s: float, where: str) -> Plant:
        """The component's plant: ``step`` advances one macro step of ``step_size_s``."""

    def describe(self, component: Component) -> ModelInfo:
        """The component's model as its node reports it (its FMU need not be here)."""

    def checksum(self, component: Component) -> str:
        """The SHA-256 of the FMU the component's node serves."""

    def close(self) -> None:
        """Close the session the components share (if this object opened it)."""


class SystemPlant(Plant):
    """The system of ``experiment`` (its ``system:`` section, or the SSP ``model.fmu`` names).

    A component runs in this process, in its node, or (its FMU declares
    ``canBeInstantiatedOnlyOncePerProcess``) in a child process of its own
    (:class:`~bridge.plant.isolated.IsolatedFmuPlant`), so that no two instances share it."""

    def __init__(
        self,
        experiment: Experiment,
        *,
        plants: Mapping[str, Plant] | None = None,
        remote: RemoteComponents | None = None,
    ) -> None:
        self.experiment = exp = experiment
        self.system = system = from_experiment(exp)
        self.name = f"system {exp.name!r} ({len(system.components)} components)"
        self.timing = system_timing(exp, system)
        self.plants: dict[str, Plant] = dict(plants or {})
        self._remote = remote
        try:
            self._check(exp, system)  # a node's FMU need not be here: the node describes it
            for name, component in system.components.items():
                if name not in self.plants:
                    self.plants[name] = self._component(component)
        except BaseException:
            self.close()
            raise
        self._macro = 0
        self._pending: Sequence[float] | None = None

    def _check(self, exp: Experiment, system: SystemDescription) -> None:
        self.infos = {
            n: self.plants[n].info if n in self.plants else component_info(c, self._remote, system.where)
            for n, c in system.components.items()
        }
        self.system = system = expand_arrays(system, self.infos)  # whole arrays: element by element
        self.couplings: dict[Connection, Convert | None] = {}
        self.warnings = [*system.warnings, *check_system(system, self.infos, self.couplings)]
        self.feedthrough = {n: has_feedthrough(c, self.infos[n]) for n, c in system.components.items()}
        loop = find_loop(system, self.feedthrough)
        if loop and system.max_iterations <= 1:
            raise loop_error(loop, system)
        self.info = system_info(exp, system, self.infos, self.timing)
        _check_driven(exp, system)

    def _component(self, component: Component) -> Plant:
        t, where = self.timing, self.system.where
        if component.node is None:
            from bridge.plant.system.component import FmuComponent, component_plant_spec

            spec = component_plant_spec(component, t.step_size_s, t.start_time_s, where)
            if self.infos[component.name].once_per_process:  # never beside another instance
                from bridge.plant.isolated import IsolatedFmuPlant

                section = self.experiment.model.isolation  # its limits, where the file sets them
                if section is None:
                    return IsolatedFmuPlant(spec)
                return IsolatedFmuPlant(
                    spec,
                    timeout_s=section.timeout,
                    memory_limit_mb=section.memory_limit_mb,
                    restart=section.restart,
                )
            return FmuComponent(spec)
        if self._remote is None:
            raise ConfigError(
                f"system.components: {component.name!r} runs in node {component.node!r}, and this "
                f"system was built without the network; use FmuEnv (it connects to nodes){where}"
            )
        return self._remote(component, t.step_size_s, t.start_time_s, where)

    # -- wiring ------------------------------------------------------------------------------------
    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        system, where = self.system, self.system.where
        ins: dict[str, list[str]] = {n: [] for n in system.components}
        outs: dict[str, list[str]] = {n: [] for n in system.components}
        external = [split_name(n, system.components, "actions", where) for n in self.input_names]
        observed = [split_name(n, system.components, "observations", where) for n in self.output_names]
        for name, info in self.infos.items():  # every numeric output, for the per-component recording
            for var in info.by_causality("output"):
                for element in var.element_names() if var.is_numeric else ():  # String, Binary: not bound
                    _add(outs, Endpoint(name, element))
        for c in system.connections:  # in the order a component's node serves them
            _add(outs, c.source)
            _add(ins, c.target)
        for e in external:
            _add(ins, e)
        for e in observed:  # a connected input too: read from its FMU, the value it held for the step
            _add(outs, e)
        for name, plant in self.plants.items():
            plant.bind(ins[name], outs[name])
        self.links = [
            Link(c.source.component, outs[c.source.component].index(c.source.variable),
                 c.target.component, ins[c.target.component].index(c.target.variable),
                 self.couplings.get(c))
            for c in system.connections
        ]  # fmt: skip
        self._external = [(e.component, ins[e.component].index(e.variable)) for e in external]
        self._observed = [(e.component, outs[e.component].index(e.variable)) for e in observed]
        self._start = {n: np.array([_start(self.infos[n], v) for v in ins[n]], dtype=np.float64) for n in ins}
        if system.algorithm == "gauss_seidel":
            order = gauss_seidel_order(system, self.feedthrough)
        else:  # order-free: components here step while those in nodes do, then nodes are awaited
            order = sorted(ins, key=lambda n: system.components[n].node is not None)
        self._plant_list = list(self.plants.values())
        through = [n for n, f in self.feedthrough.items() if f]
        self.master = Master(
            system, self.plants, self.links, order, init_order(system, self.feedthrough), settle=through
        )
        self.master.external, self.master.observed = self._external, self._observed
        self._steps = self.timing.steps_per_sample

    # -- the plant interface -----------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return self.timing.start_time_s + self._macro * self.timing.step_size_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated, self._macro = 0, False, 0
        by_component: dict[str, dict[str, Any]] = {n: {} for n in self.system.components}
        for name, value in values.items():
            end = split_name(name, self.system.components, "values", self.system.where)
            by_component[end.component][end.variable] = value
        start = {n: u.copy() for n, u in self._start.items()}
        self._write(start, inputs)
        try:
            self.master.initialize(by_component, start)
        except PlantError as exc:
            raise self._component_failed(exc, step=None) from exc
        return self._read()

    def _write(self, target: Mapping[str, FloatArray], inputs: Sequence[float] | None) -> None:
        if inputs is not None:
            for (name, j), value in zip(self._external, inputs):
                target[name][j] = value

    def _read(self) -> FloatArray:
        outputs = self.master.outputs
        return np.array([outputs[name][i] for name, i in self._observed], dtype=np.float64)

    def send(self, inputs: Sequence[float] | None) -> None:
        self._pending = inputs

    def receive(self) -> FloatArray:
        return self.step(self._pending)

    def step(self, inputs: Sequence[float] | None) -> FloatArray:
        master = self.master
        native = master.native
        if native is not None:  # inputs, the sample's macro steps and the observation in one native call
            try:
                observation = native.sample(inputs, self._steps)
            except PlantError as exc:
                self._macro += native.done
                self.terminated = True
                raise self._component_failed(exc) from exc
            done = native.done
            self._macro += done
            self.sample += 1
            if done < self._steps or native.stopped:
                self.terminated = True
            return observation
        self._write(master.inputs, inputs)
        plants = self._plant_list
        for _ in range(self.timing.steps_per_sample):
            try:
                master.step()
            except PlantError as exc:
                self.terminated = True
                raise self._component_failed(exc) from exc
            self._macro += 1
            if any([p.terminated for p in plants]):
                self.terminated = True
                break
        self.sample += 1
        return self._read()

    def _component_failed(self, exc: PlantError, **fields: Any) -> PlantError:
        """The component's error as the system's, same kind, naming the component."""
        verb = {PlantDied: "died", StepError: "failed"}.get(type(exc), "did not answer")
        hint = "the node may be overloaded, hung or unreachable; timeout_s sets the limit"
        if isinstance(exc, StepError):
            fields["log"], hint = exc.log, exc.hint or MODEL_FAILED_HINT
        elif isinstance(exc, PlantDied):
            hint = "restart its node (fmu-bridge system serve) and reset"
        elif exc.what == MODEL_HUNG:  # the node's deadline passed: its words, as a remote env gives them
            verb, hint = "hung", exc.hint
        error = self.failure(type(exc), f"{exc.plant} {verb}", exc.detail, hint, **fields)
        error.component = next((n for n, p in self.plants.items() if p.name == exc.plant), "")  # type: ignore[attr-defined]
        return error

    def component_outputs(self) -> dict[str, dict[str, float]]:
        """Every output of every component now (and any other variable the task reads), by
        component, for recording; the order is fixed once bound."""
        return {
            n: dict(zip(p.output_names, map(float, self.master.outputs[n]))) for n, p in self.plants.items()
        }

    def component_values(self) -> FloatArray:
        """The values of :meth:`component_outputs`, flat in the same order (cheap, per step)."""
        return np.concatenate([self.master.outputs[n] for n in self.plants])

    @property
    def can_set_values(self) -> bool:  # type: ignore[override]
        return all(p.can_set_values for p in self.plants.values())

    def set_values(self, values: Mapping[str, Any]) -> None:
        grouped: dict[str, dict[str, Any]] = {}
        for name, value in values.items():
            end = split_name(name, self.system.components, "hooks.state", self.system.where)
            grouped.setdefault(end.component, {})[end.variable] = value
        for name, group in grouped.items():
            self.plants[name].set_values(group)

    def provenance(self) -> dict[str, str]:
        return {"fmu": str(self.system.source or ""), "fmu_sha256": "", "node": ""}

    def close(self) -> None:
        for plant in getattr(self, "plants", {}).values():
            plant.close()
        remote = getattr(self, "_remote", None)
        if remote is not None:
            remote.close()
            self._remote = None


def describe_system(experiment: Experiment, remote: RemoteComponents | None = None) -> ModelInfo:
    """The system of ``experiment`` as one model (``component.variable``), none started: each
    FMU read here, or described by its node (``remote``) when the component runs in a node and
    its FMU is not on this machine."""
    system = from_experiment(experiment)
    infos = {n: component_info(c, remote, system.where) for n, c in system.components.items()}
    check_system(expand_arrays(system, infos), infos)  # connections and parameters, as the plant checks them
    from bridge.plant.system.component import steps_per_macro

    timing = system_timing(experiment, system)
    for component in system.components.values():  # each component's step, as the plant divides it
        steps_per_macro(component, timing.step_size_s, None, system.where)
    return system_info(experiment, system, infos, timing)


def sized_info(component: Component, info: ModelInfo) -> ModelInfo:
    """``info`` with the array sizes the component's structural parameters give."""
    if not component.structural_parameters:
        return info
    from bridge.fmu import structure

    key = f"system.components.{component.name}.structural_parameters"
    return structure.resized(
        info, structure.sizes_of(structure.check(info, component.structural_parameters, key))
    )


def component_info(component: Component, remote: RemoteComponents | None, where: str) -> ModelInfo:
    """The component's model: its FMU's description, else (a node's component) its node's."""
    from bridge.fmu import read_model_info

    if component.node is None or component.fmu.exists():
        return sized_info(component, read_model_info(component.fmu))
    if remote is None:
        raise ConfigError(
            f"system.components.{component.name}.fmu: {component.fmu} is not on this machine; the "
            f"component runs in node {component.node!r}, which can describe it: use the env layer "
            f"(bridge.env.plants.model_info_for), which asks the node{where}"
        )
    return remote.describe(component)


def system_checksum(experiment: Experiment, remote: RemoteComponents | None = None) -> str:
    """The SHA-256 over the components' FMU hashes (a node's FMU: the hash its node reports)."""
    from bridge.fmu import sha256

    system = from_experiment(experiment)
    hashes = []
    for name, c in system.components.items():
        if c.node is None or c.fmu.exists():
            hashes.append(f"{name}:{sha256(c.fmu)}")
        else:
            component_info(c, remote, system.where)  # a clear error without a node to ask
            hashes.append(f"{name}:{remote.checksum(c)}")  # type: ignore[union-attr]
    return hashlib.sha256("\n".join(hashes).encode()).hexdigest()


def _add(names: dict[str, list[str]], end: Endpoint) -> None:
    if end.variable not in names[end.component]:
        names[end.component].append(end.variable)


def _start(info: ModelInfo, name: str) -> float:
    """The start value of a variable or of one element ``u[2]`` of an array (0 without one)."""
    var, index = info.element(name)
    start = var.start
    if index is not None:
        start = start[index] if isinstance(start, (list, tuple)) and index < len(start) else None
    try:
        return float(start) if start is not None else 0.0
    except (TypeError, ValueError):
        return 0.0


def system_timing(exp: Experiment, system: SystemDescription) -> Timing:
    """Macro step ``model.step_size`` (or the SSP's), samples of whole macro steps; the start time
    ``model.start_time`` where the experiment sets it, else the system file's (SSP ``startTime``,
    OSP ``StartTime``), else 0."""
    h = exp.model.step_size or system.step_size_s
    if h is None:
        raise ConfigError(
            f"model.step_size: a system needs its macro step (seconds); set model.step_size{system.where}"
        )
    n = sampling_ratio(exp.model.sampling_time or h, h)
    start = exp.model.start_time
    if "start_time" not in exp.model.model_fields_set and system.start_time_s is not None:
        start = system.start_time_s
    return Timing(step_size_s=h, steps_per_sample=n, sampling_time_s=n * h, start_time_s=start)


def system_info(
    exp: Experiment, system: SystemDescription, infos: Mapping[str, ModelInfo], t: Timing
) -> ModelInfo:
    """The system as one model: every component's variables as ``component.variable``; a
    connected input is the system's own (causality local): observable, not the task's to drive."""
    driven = {str(c.target) for c in system.connections}
    variables = {
        f"{n}.{v.name}": dataclasses.replace(
            v, name=f"{n}.{v.name}", causality="local" if f"{n}.{v.name}" in driven else v.causality
        )
        for n, info in infos.items()
        for v in info.variables.values()
    }
    return ModelInfo(
        path=system.source or Path(exp.name),
        fmi_version="2.0",
        model_name=exp.name,
        guid="",
        interfaces=("cs",),
        model_identifiers={},
        default_experiment=DefaultExperiment(t.start_time_s, None, t.step_size_s, None),
        platforms=(),
        variables=variables,
        can_get_set_state={"cs": all(i.can_get_set_state.get("cs", False) for i in infos.values())},
        description=f"system of {', '.join(system.components)}",
    )


def _check_driven(exp: Experiment, system: SystemDescription) -> None:
    driven = {str(c.target): c for c in system.connections}
    for key, names in (("actions.inputs", exp.actions.inputs), ("scenarios.inputs", scenario_inputs(exp))):
        for name in names:
            if name in driven:
                raise ConfigError(
                    f"{key}: {name!r} is driven by the connection {driven[name]}; the task can only "
                    f"drive inputs no connection drives{system.where}"
                )
