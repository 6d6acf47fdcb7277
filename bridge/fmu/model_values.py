"""The settings and initial values of a :class:`~bridge.fmu.model.Model`, checked and written.

Which interface, step size and solver a model runs with; its structural parameters, set in
configuration mode (:func:`configure`); and the parameters and start values of an
initialisation: scalars, whole FMI 3.0 arrays, and array elements (``A[1,2]``, named as actions
name them) gathered per array as :class:`Elements`, written over the array's current values.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bridge.errors import ConfigError, FmuError, VariableError
from bridge.fmu import access, structure
from bridge.fmu.backend import Backend
from bridge.fmu.description import Interface, ModelInfo, Variable
from bridge.fmu.fixed_step import METHODS
from bridge.fmu.spec import Solver

SOLVERS: tuple[str, ...] = ("cvode", *METHODS)
ToC = Callable[[Variable, Any], Any]  # a value as the FMU's C type takes it (checked)
Element = Callable[[str, str], tuple[Variable, "int | None"]]  # a name as (variable, flat index)


def choose_interface(info: ModelInfo, interface: str) -> Interface:
    if interface == "auto":  # co-simulation, else model exchange, else scheduled execution
        return next(i for i in ("cs", "me", "se") if i in info.interfaces)
    if interface not in ("cs", "me", "se"):
        raise ConfigError(f"interface {interface!r} is unknown; expected 'cs', 'me', 'se' or 'auto'")
    if interface not in info.interfaces:
        raise ConfigError(
            f"{info.path.name} has no {interface.upper()} interface; it provides "
            f"{', '.join(i.upper() for i in info.interfaces)} [{info.path}]"
        )
    return interface


def check_solver(info: ModelInfo, interface: Interface, solver: str, substeps: int) -> tuple[Solver, int]:
    if solver not in SOLVERS:
        raise ConfigError(f"solver {solver!r} is unknown; expected one of {SOLVERS}")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"solver_substeps must be a whole number >= 1, got {substeps!r}")
    if solver != "cvode" and (interface != "me" or info.fmi_major < 2):
        raise ConfigError(
            f"solver {solver!r} integrates FMI 2.0/3.0 model exchange, but {info.path.name} runs "
            f"FMI {info.fmi_version} {interface.upper()}: choose interface 'me' (FMI 2.0/3.0) "
            f"or solver 'cvode'"
        )
    return solver, substeps  # type: ignore[return-value]


def step_size(info: ModelInfo, step_size_s: float | None) -> float:
    h = step_size_s if step_size_s is not None else info.default_experiment.step_size_s
    if h is None:
        raise ConfigError(
            f"{info.path.name} has no default step size: pass step_size_s (the FMU step size in seconds)"
        )
    if not (math.isfinite(h) and h > 0):
        raise ConfigError(f"step size must be a positive finite number of seconds, got {h!r}")
    return float(h)


@dataclass(frozen=True)
class Elements:
    """Some elements of an FMI 3.0 array to set at initialisation: ``(flat index, value)``, sorted."""

    items: tuple[tuple[int, Any], ...]


def whole_array(var: Variable, value: Any) -> list[Any]:
    given: list[Any] = np.asarray(value, dtype=object).reshape(-1).tolist()
    if len(given) != var.size:
        raise VariableError(
            f"{var.name!r} is an array of shape {var.dimensions} ({var.size} elements), got {len(given)} "
            f"values; give all of them, or single elements as {var.element_names()[0]!r}"
        )
    return given


def by_name(values: Mapping[Variable, Any]) -> dict[str, Any]:
    """Initial values by the names they were given: array elements by their element names."""
    named: dict[str, Any] = {}
    for var, value in values.items():
        if isinstance(value, Elements):
            names = var.element_names()
            named.update((names[index], x) for index, x in value.items)
        else:
            named[var.name] = value
    return named


def freeze(values: Mapping[Variable, Any]) -> tuple[Any, ...]:
    return tuple(sorted((v.name, repr(x)) for v, x in values.items()))


def not_settable_at_init(var: Variable, info: ModelInfo) -> str:
    if var.causality == "structuralParameter":
        return (
            f"{var.name!r} of {info.model_name} is a structural parameter (an array size): it is set in "
            f"configuration mode, once per instance, not at initialisation; give it as "
            f"Model(structural_parameters={{{var.name!r}: ...}}) or under model.structural_parameters "
            f"in the experiment"
        )
    return (
        f"{var.name!r} of {info.model_name} cannot be set: it is a {var.variability} "
        f"{var.causality} (initial={var.initial}); only parameters, inputs and variables with "
        f"initial exact/approx take values at initialisation"
    )


def not_settable_in_step(var: Variable, info: ModelInfo) -> str:
    if var.settable_at_init:
        return (
            f"{var.name!r} of {info.model_name} is a {var.variability} {var.causality}: it can only be "
            f"set at initialisation; pass it to reset(values) instead"
        )
    return not_settable_at_init(var, info)


def checked(info: ModelInfo, values: Mapping[str, Any], element: Element, to_c: ToC) -> dict[Variable, Any]:
    """Parameters and start values by variable: scalars, whole FMI 3.0 arrays, and array elements
    (``A[1,2]``, named as actions name them) gathered per array as :class:`Elements`."""
    result: dict[Variable, Any] = {}
    elements: dict[Variable, dict[int, Any]] = {}
    for name, value in values.items():
        var, index = element(name, "parameter or start value")
        if not var.settable_at_init:
            raise VariableError(not_settable_at_init(var, info))
        if index is not None:
            to_c(var, value)
            elements.setdefault(var, {})[index] = value
            continue
        for x in whole_array(var, value) if var.dimensions else [value]:
            to_c(var, x)
        result[var] = value
    for var, items in elements.items():
        if var in result:
            raise VariableError(
                f"{var.name!r} of {info.model_name} is given both whole and by element; give one or the other"
            )
        result[var] = Elements(tuple(sorted(items.items())))
    return result


def split_early(values: Mapping[Variable, Any], major: int) -> tuple[list[Variable], list[Variable]]:
    """The values set before initialisation mode, and those set in it. FMI 1.0 takes every start
    value before fmiInitialize; 2.0/3.0 calculated ones in init mode, and array elements there too:
    the other elements are read first, which FMI 3.0 allows only from initialisation mode on."""
    early = [
        v
        for v in values
        if not isinstance(values[v], Elements)
        and (major == 1 or v.causality == "input" or v.initial in ("exact", "approx"))
    ]
    return early, [v for v in values if v not in early]


def write(
    backend: Backend,
    variables: Sequence[Variable],
    values: Mapping[Variable, Any],
    to_c: ToC,
    where: Callable[[], str],
) -> None:
    """Initial values: scalars, whole arrays, and array elements over the array's current values."""
    if not variables:
        return
    partial = [v for v in variables if isinstance(values[v], Elements)]
    current = access.read(backend, partial, where) if partial else {}
    flat: dict[str, list[Any]] = {}
    for v in variables:
        value = values[v]
        if isinstance(value, Elements):
            row = [to_c(v, x) for x in current[v.name]]
            for index, x in value.items:
                row[index] = to_c(v, x)
            flat[v.name] = row
        elif v.dimensions:
            flat[v.name] = [to_c(v, x) for x in whole_array(v, value)]
        else:
            flat[v.name] = [to_c(v, value)]
    access.write(backend, list(variables), flat, where)


def configure(
    backend: Any,
    info: ModelInfo,
    values: Mapping[Variable, int],
    to_c: Callable[[Variable, Any], Any],
    where: Callable[[], str],
) -> ModelInfo:
    """Set the structural parameters ``values`` in configuration mode (``backend``: a
    :class:`bridge.fmu.backend.Backend` with an instance); ``info`` with the sizes the FMU reports."""
    wanted = structure.integer_structural(info)
    backend.call("fmi3EnterConfigurationMode", backend.fmu.enterConfigurationMode)
    try:
        flat = {v.name: [to_c(v, value)] for v, value in values.items()}
        access.write(backend, list(values), flat, where)
        read = access.read(backend, wanted, where)  # the sizes the FMU reports, not what was asked
    finally:
        backend.call("fmi3ExitConfigurationMode", backend.fmu.exitConfigurationMode)
    sizes = {v.value_reference: int(read[v.name][0]) for v in wanted}
    wrong = structure.refused(info, values, sizes)
    if wrong is not None:
        raise FmuError(wrong, log=backend.log.recent())
    return structure.resized(info, sizes)
