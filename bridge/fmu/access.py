"""Reading and writing variables by value reference: scalars, FMI 3.0 arrays and Binary.

Values travel as flat lists per variable (row-major for arrays, as FMI 3.0 stores them), one FMI
call per type. These are the set-up and occasional paths (``Model.get``/``Model.set``,
initialisation); the per-sample path is :class:`~bridge.fmu.signals.SignalGroup`.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np

from bridge.errors import FmuError, VariableError
from bridge.fmu.abi import STATUS_NAMES, WARNING
from bridge.fmu.backend import Backend
from bridge.fmu.description import Variable
from bridge.fmu.values import from_c

Where = Callable[[], str]


def read(backend: Backend, variables: Sequence[Variable], where: Where) -> dict[str, list[Any]]:
    """Current values of ``variables``: name -> flat list of typed values."""
    values: dict[str, list[Any]] = {}
    for var_type, group in by_type(variables).items():
        if var_type == "Binary":
            raw = backend.call("fmi3GetBinary", partial(backend.fmu.getBinary, _vrs(group), _total(group)))
            _split(group, [bytes(b) for b in raw], values)
            continue
        if var_type == "Clock":
            raise VariableError(f"{[v.name for v in group]} are clocks: they are listed, not read")
        buf = (backend.ctype(var_type) * _total(group))()
        _call(backend, var_type, group, buf, setter=False, where=where)
        _split(group, [from_c(raw, var_type) for raw in buf], values)
    return values


def write(
    backend: Backend, variables: Sequence[Variable], flat: Mapping[str, list[Any]], where: Where
) -> None:
    """Write checked, converted values (name -> flat list, see :func:`merge`) with one call per type."""
    for var_type, group in by_type(variables).items():
        items = [x for v in group for x in flat[v.name]]
        if var_type == "Binary":
            backend.call("fmi3SetBinary", partial(backend.fmu.setBinary, _vrs(group), items))
            continue
        buf = (backend.ctype(var_type) * len(items))(*items)
        _call(backend, var_type, group, buf, setter=True, where=where)


def merge(
    backend: Backend,
    elements: Mapping[str, tuple[Variable, int | None]],
    values: Mapping[str, Any],
    convert: Callable[[Variable, Any], Any],
    where: Where,
) -> dict[str, list[Any]]:
    """Flat value lists to write: whole arrays as given; single elements over the array's current values."""
    partial = [var for var, index in elements.values() if index is not None]
    current = read(backend, list(dict.fromkeys(partial)), where) if partial else {}
    flat: dict[str, list[Any]] = {}
    for name, (var, index) in elements.items():
        if index is not None:
            row = flat.setdefault(var.name, [convert(var, x) for x in current[var.name]])
            row[index] = convert(var, values[name])
        elif var.dimensions:
            given = np.asarray(values[name], dtype=object).reshape(-1).tolist()
            if len(given) != var.size:
                raise VariableError(
                    f"{name!r} is an array of shape {var.dimensions} ({var.size} elements), got "
                    f"{len(given)} values"
                )
            flat[var.name] = [convert(var, x) for x in given]
        else:
            flat[var.name] = [convert(var, values[name])]
    return flat


def pick(var: Variable, flat: list[Any], index: int | None) -> Any:
    """One element, the scalar, or the whole array shaped by its dimensions."""
    if index is not None:
        return flat[index]
    if var.dimensions:
        return np.array(flat).reshape(var.dimensions)
    return flat[0]


def by_type(variables: Sequence[Variable]) -> dict[str, list[Variable]]:
    groups: dict[str, list[Variable]] = {}
    for var in variables:
        groups.setdefault(var.type, []).append(var)
    return groups


def _vrs(group: Sequence[Variable]) -> list[int]:
    return [v.value_reference for v in group]


def _total(group: Sequence[Variable]) -> int:
    return sum(v.size for v in group)


def _split(group: Sequence[Variable], items: list[Any], out: dict[str, list[Any]]) -> None:
    start = 0
    for var in group:
        out[var.name] = items[start : start + var.size]
        start += var.size


def _call(
    backend: Backend, var_type: str, group: list[Variable], buf: Any, *, setter: bool, where: Where
) -> None:
    fn = backend.accessor(var_type, setter=setter)
    vrs = (ctypes.c_uint * len(group))(*_vrs(group))
    extra = (len(buf),) if backend.major == 3 else ()  # FMI 3.0: the number of values, arrays expanded
    status = fn(backend.component, vrs, len(group), buf, *extra)
    if status > WARNING:
        what = "set" if setter else "get"
        raise FmuError(
            f"{backend.info.model_name}: {what} of {[v.name for v in group]} returned "
            f"{STATUS_NAMES[status]} {where()}",
            log=backend.log.recent(),
        )
