"""Checks of a system against its FMUs: every connection valid, before anything runs.

Errors name the connection, the component, the variable and the file: an unknown component or
variable, a connection that does not run from an output to an input, an input driven twice,
types that do not convert, a parameter the FMU does not take, a transformation that does not fit
the connectors, units of different quantities (``transform``). Units that cannot be compared (a
name without a definition) are a warning.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
from collections.abc import Mapping

from bridge.errors import ConfigError, VariableError
from bridge.fmu.clock_rules import check_settings
from bridge.fmu.vocab import ModelInfo, Variable
from bridge.plant.system.description import Connection, Endpoint, SystemDescription
from bridge.plant.system.transform import Convert, coupling

_log = logging.getLogger(__name__)
_FLOATS = ("Float32", "Float64")
_INTEGERS = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Enumeration")


def check_system(
    system: SystemDescription,
    infos: Mapping[str, ModelInfo],
    couplings: dict[Connection, Convert | None] | None = None,
) -> list[str]:
    """Raise :class:`ConfigError` on the first invalid connection or parameter; return warnings.

    ``couplings`` (if given) receives what each connection does to its value on the way (unit
    conversion and transformation; None: passed unchanged)."""
    warnings: list[str] = []
    driven: dict[Endpoint, Connection] = {}
    for c in system.connections:
        source = _variable(c, c.source, infos, system)
        target = _variable(c, c.target, infos, system)
        _check_roles(c, source, target, system)
        if c.target in driven:
            raise ConfigError(
                f"connection {c}: input {c.target} is already driven by {driven[c.target]}; "
                f"an input takes one connection{system.where}"
            )
        driven[c.target] = c
        _check_types(c, source, target, system)
        _check_shapes(c, source, target, system)
        carried = coupling(c, source, target, infos, system)
        if carried.warning:
            warnings.append(carried.warning)
        if couplings is not None:
            couplings[c] = carried.convert
    for name, component in system.components.items():
        if component.clock_intervals or component.clock_schedule:
            try:
                check_settings(
                    infos[name], component.interface, component.clock_intervals, component.clock_schedule
                )
            except ConfigError as exc:
                raise ConfigError(f"system.components.{name}: {exc}{system.where}") from None
        given = [("parameters", n) for n in component.parameters]
        for key, var_name in given + [("start_values", n) for n in component.start_values]:
            var = _known(Endpoint(name, var_name), infos[name], f"system.components.{name}.{key}", system)
            if not var.settable_at_init:
                hint = (
                    f"; give it under system.components.{name}.structural_parameters"
                    if var.causality == "structuralParameter"
                    else ""
                )
                raise ConfigError(
                    f"system.components.{name}.{key}: {var_name!r} is a {var.variability} "
                    f"{var.causality} of {infos[name].model_name} and cannot be set{hint}{system.where}"
                )
    for text in warnings:
        _log.warning("%s", text)
    return warnings


def expand_arrays(system: SystemDescription, infos: Mapping[str, ModelInfo]) -> SystemDescription:
    """``system`` with each connection between two whole FMI 3.0 arrays of one shape replaced by
    one connection per element, in row-major order (``a.y -> b.u``: ``a.y[1] -> b.u[1]``, ...),
    each keeping the connection's transformation; arrays of different shapes are refused with both
    shapes. A scalar to an array stays as written (:func:`check_system` refuses it)."""
    connections: list[Connection] = []
    expanded = False
    for c in system.connections:
        source, target = _array(c.source, infos), _array(c.target, infos)
        if source is None or target is None:
            connections.append(c)
            continue
        expanded = True
        if source.dimensions != target.dimensions:
            raise ConfigError(
                f"connection {c}: {c.source} is {_shape(source.dimensions)} and {c.target} is "
                f"{_shape(target.dimensions)}; whole arrays connect element by element and need one "
                f"shape: connect elements by name instead ({c.source}[1] -> {c.target}[1], ...)"
                f"{system.where}"
            )
        for y, u in zip(source.element_names(), target.element_names()):
            connections.append(
                dataclasses.replace(
                    c, source=Endpoint(c.source.component, y), target=Endpoint(c.target.component, u)
                )
            )
    return dataclasses.replace(system, connections=tuple(connections)) if expanded else system


def _array(end: Endpoint, infos: Mapping[str, ModelInfo]) -> Variable | None:
    info = infos.get(end.component)
    var = info.variables.get(end.variable) if info is not None else None
    return var if var is not None and var.dimensions else None


def _variable(
    c: Connection, end: Endpoint, infos: Mapping[str, ModelInfo], system: SystemDescription
) -> Variable:
    if end.component not in infos:
        raise ConfigError(
            f"connection {c}: {end.component!r} is not a component; components: "
            f"{list(system.components)}{system.where}"
        )
    return _known(end, infos[end.component], f"connection {c}", system)


def _known(end: Endpoint, info: ModelInfo, key: str, system: SystemDescription) -> Variable:
    var = info.variables.get(end.variable)
    if var is None and "[" in end.variable:  # one element of an FMI 3.0 array: a scalar
        try:
            array, _ = info.element(end.variable)
        except VariableError as exc:
            raise ConfigError(f"{key}: {exc}{system.where}") from None
        return dataclasses.replace(array, name=end.variable, dimensions=(), start=None)
    if var is None:
        close = difflib.get_close_matches(end.variable, list(info.variables), n=4, cutoff=0.5)
        hint = f"did you mean {close}?" if close else f"`fmu-bridge inspect {info.path}` lists them"
        raise ConfigError(
            f"{key}: {end.variable!r} is not a variable of component {end.component!r} "
            f"({info.path.name}); {hint}{system.where}"
        )
    return var


def _check_roles(c: Connection, source: Variable, target: Variable, system: SystemDescription) -> None:
    if source.causality not in ("output", "parameter", "calculatedParameter"):
        raise ConfigError(
            f"connection {c}: the source {c.source} is a{_an(source.causality)} {source.causality}; a "
            f"connection starts at an output{system.where}"
        )
    if target.causality != "input":
        raise ConfigError(
            f"connection {c}: the target {c.target} is a{_an(target.causality)} {target.causality}, not an "
            f"input; connections run from an output to an input (output -> output is not allowed)"
            f"{system.where}"
        )


def _an(word: str) -> str:
    return "n" if word[:1] in "aeiou" else ""


def _check_types(c: Connection, source: Variable, target: Variable, system: SystemDescription) -> None:
    for var, end in ((source, c.source), (target, c.target)):
        if not var.is_numeric:
            raise ConfigError(
                f"connection {c}: {end} is a {var.type} variable; connections carry numbers "
                f"(Float, Int, Boolean, Enumeration): a {var.type} output can be read and recorded, "
                f"not connected{system.where}"
            )
    if source.type == target.type or (source.type in _FLOATS and target.type in _FLOATS):
        return
    if source.type in (*_INTEGERS, "Boolean") and target.type in _FLOATS:
        return  # exact: every integer and boolean value is a float value
    if source.type in _INTEGERS and target.type in _INTEGERS:
        return
    raise ConfigError(
        f"connection {c}: {c.source} is {source.type} and {c.target} is {target.type}; there is no "
        f"lossless conversion (integers and booleans may feed floats, not the other way){system.where}"
    )


def _check_shapes(c: Connection, source: Variable, target: Variable, system: SystemDescription) -> None:
    """A connection joins one scalar to one scalar: an array end must name one element."""
    shapes = [(end, var.dimensions) for end, var in ((c.source, source), (c.target, target))]
    if any(dims for _, dims in shapes):
        text = " and ".join(f"{end} is {_shape(dims)}" for end, dims in shapes)
        element = next(f"{end}[{','.join('1' * len(dims))}]" for end, dims in shapes if dims)
        raise ConfigError(
            f"connection {c}: {text}; a connection joins one scalar to one scalar: name the array "
            f"element, for example {element} (1-based indices, one per dimension){system.where}"
        )


def _shape(dims: tuple[int, ...]) -> str:
    return f"an array of shape {list(dims)}" if dims else "a scalar"
