"""What a system is: components (FMUs), connections and parameter bindings.

Built from the experiment's ``system:`` section (:func:`from_experiment`) or from an SSP 1.0
file (:mod:`bridge.plant.system.ssp`); the two give the same :class:`SystemDescription` (its
parts are data in :mod:`bridge.plant.system.structure`, re-exported here).
"""

from __future__ import annotations

from pathlib import Path

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.experiment.system import CONNECTION, SystemSection, is_system_file
from bridge.plant.system.ssp import read_ssp
from bridge.plant.system.structure import (
    Algorithm,
    Component,
    Connection,
    Endpoint,
    SystemDescription,
    Transform,
    Unit,
)

__all__ = [
    "Algorithm",
    "Component",
    "Connection",
    "Endpoint",
    "SystemDescription",
    "Transform",
    "Unit",
    "from_experiment",
    "parse_connection",
    "split_name",
]


def parse_connection(text: str, where: str = "") -> Connection:
    """``"a.y -> b.u"`` as a :class:`Connection`."""
    match = CONNECTION.match(text)
    if match is None:
        raise ConfigError(f"system.connections: {text!r} is not of the form 'a.y -> b.u'{where}")
    a, y, b, u = match.groups()
    return Connection(Endpoint(a, y), Endpoint(b, u))


def split_name(name: str, components: dict[str, Component], key: str, where: str = "") -> Endpoint:
    """``component.variable`` split at the first dot; the component must exist."""
    component, dot, variable = name.partition(".")
    if not dot or not variable:
        raise ConfigError(
            f"{key}: {name!r} is not of the form component.variable; components: {list(components)}{where}"
        )
    if component not in components:
        raise ConfigError(
            f"{key}: {name!r} names component {component!r}, which is not in the system; "
            f"components: {list(components)}{where}"
        )
    return Endpoint(component, variable)


def from_experiment(experiment: Experiment, *, check_files: bool = True) -> SystemDescription:
    """The system of ``experiment``: its ``system:`` section, or the SSP that ``model.fmu`` names
    (merged with a ``system:`` section's algorithm, extra connections and parameters).

    A component's FMU file must exist unless the component runs in a node (its FMU may be only
    on the node's machine), or ``check_files`` is False (a machine serving some components
    needs only their FMUs: ``bridge.net.system_node`` checks those)."""
    section = experiment.system or SystemSection()
    where = f" [{experiment.source}]" if experiment.source else ""
    for key in ("clock_intervals", "clock_schedule"):
        if getattr(experiment.model, key):
            raise ConfigError(
                f"model.{key}: a system's clocks belong to its components, and model.{key} names "
                f"none; move it to system.components.NAME.{key} of the component whose FMU has the "
                f"clocks{where}"
            )
    base: SystemDescription | None = None
    if is_system_file(experiment.model.fmu):
        base = read_ssp(_path(experiment.model.fmu, experiment, "model.fmu"))
    components = dict(base.components) if base else {}
    for name, spec in section.components.items():
        old = components.get(name)
        if not spec.fmu and old is None:
            raise ConfigError(f"system.components.{name}.fmu: give the component's FMU{where}")
        fmu = (
            _component_fmu(spec.fmu, experiment, name, must_exist=check_files and spec.node is None)
            if spec.fmu
            else (old.fmu if old else Path())
        )
        parameters = {**(old.parameters if old else {}), **spec.parameters}
        interface = spec.interface if spec.interface != "auto" or old is None else old.interface
        units = old.connector_units if old else {}
        sizes, intervals, schedule = (
            {**(getattr(old, key) if old else {}), **getattr(spec, key)}  # the file's names win
            for key in ("structural_parameters", "clock_intervals", "clock_schedule")
        )
        # a key the section leaves out keeps the file's value (its step size above all)
        policy = spec.reset_policy
        components[name] = Component(
            name,
            fmu,
            parameters,
            spec.step_size if spec.step_size is not None else (old.step_size_s if old else None),
            interface,
            spec.feedthrough if spec.feedthrough is not None or old is None else old.feedthrough,
            spec.node if spec.node is not None or old is None else old.node,
            units,
            sizes,
            intervals,
            schedule,
            start_values=dict(spec.start_values),
            reset_policy=policy if isinstance(policy, str) else "auto",
            state_file=None
            if isinstance(policy, str)
            else _path(policy.state_file, experiment, f"system.components.{name}.reset_policy.state_file"),
            tolerance=spec.tolerance,
            solver=spec.solver,
            solver_substeps=spec.solver_substeps,
        )
    if not components:
        raise ConfigError(f"system.components: a system needs at least one component{where}")
    connections = (base.connections if base else ()) + tuple(
        parse_connection(c, where) for c in section.connections
    )
    iteration = section.iteration
    return SystemDescription(
        components=components,
        connections=connections,
        algorithm=section.algorithm,
        max_iterations=iteration.max_iterations if iteration else 1,
        tolerance=iteration.tolerance if iteration else 1e-10,
        order=tuple(section.order),
        feedthrough_outputs=section.feedthrough_outputs,
        step_size_s=base.step_size_s if base else None,
        source=experiment.source,
        units=base.units if base else {},
        ssp=base.source if base else None,
        duration_s=base.duration_s if base else None,
        start_time_s=base.start_time_s if base else None,
        warnings=base.warnings if base else (),
    )


def _component_fmu(spec: str, experiment: Experiment, name: str, *, must_exist: bool) -> Path:
    if spec.startswith("example:"):
        from bridge.models import example_fmu

        parts = spec.split(":")[1:]
        version = parts[1] if len(parts) > 1 and parts[1] else "2.0"
        return example_fmu(parts[0], version, parts[2] if len(parts) > 2 else "cs")
    return _path(spec, experiment, f"system.components.{name}.fmu", must_exist=must_exist)


def _path(spec: str, experiment: Experiment, key: str, *, must_exist: bool = True) -> Path:
    path = Path(spec).expanduser()
    if not path.is_absolute():
        path = experiment.base_dir / path
    if must_exist and not path.exists():
        raise ConfigError(
            f"{key}: {spec!r} does not exist (looked at {path}); give a path relative to the "
            f"experiment file or example:NAME [{experiment.source}]"
        )
    return path
