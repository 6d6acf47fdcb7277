"""Structural parameters: the FMI 3.0 parameters that size arrays, set in configuration mode.

An array's ``<Dimension valueReference="..."/>`` names a structural parameter (causality
``structuralParameter``, variability ``fixed`` or ``tunable``); its start value gives the size the
model description shows. Such a parameter takes a value only in configuration mode
(``fmi3EnterConfigurationMode`` ... ``fmi3ExitConfigurationMode``), between instantiation and
initialisation, never in initialisation mode like other parameters. A :class:`~bridge.fmu.Model`
given ``structural_parameters`` does exactly that after every instantiation and fmi reset, then
reads the parameters back and sizes its arrays from what the FMU reports.

Sizes are fixed for a model's life: signal groups, observation spaces and wire frames are laid
out once. Reconfiguration during a run (tunable structural parameters in step or event mode) is
not used. This module is the FMPy-free part (checks, resizing a :class:`ModelInfo`), which
experiment checks use too; the FMU calls are ``Model._configure``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from bridge.errors import ConfigError
from bridge.fmu.vocab import ModelInfo, Variable

_VARIABILITIES = ("fixed", "tunable")
_INTEGERS = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64")


def structural(info: ModelInfo) -> list[Variable]:
    """The model's structural parameters (FMI 3.0)."""
    return [v for v in info.variables.values() if v.causality == "structuralParameter"]


def check(
    info: ModelInfo, values: Mapping[str, Any], key: str = "structural_parameters"
) -> dict[Variable, int]:
    """``values`` by variable, each a structural parameter of ``info`` given a whole number >= 0.

    Raises:
        ConfigError: a name that is not a structural parameter, or a value that is not a whole number.
    """
    allowed = [v.name for v in structural(info) if v.variability in _VARIABILITIES and v.type in _INTEGERS]
    checked: dict[Variable, int] = {}
    for name, value in values.items():
        var = info.variables.get(name)
        if var is None or var.name not in allowed:
            what = (
                "not a variable"
                if var is None
                else f"a {var.variability} {var.causality} of type {var.type}, "
                "not an integer structural parameter"
            )
            raise ConfigError(
                f"{key}: {name!r} of {info.model_name} is {what}; structural parameters (array sizes, set in "
                f"FMI 3.0 configuration mode) of this model: {allowed or 'none'} [{info.path}]"
            )
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(
                f"{key}: {name} = {value!r}: expected a whole number >= 0 (an array size) [{info.path}]"
            )
        checked[var] = value
    return checked


def resized(info: ModelInfo, sizes: Mapping[int, int]) -> ModelInfo:
    """``info`` with every dimension that refers to a structural parameter (by value reference,
    ``Variable.dimension_vrs``) taken from ``sizes``; the number of continuous states follows its
    derivatives' sizes; a resized array's declared start of another length is dropped (the FMU's
    own start values for the new size are not in the description). Unchanged where nothing refers
    to ``sizes``."""
    changed: dict[str, Variable] = {}
    for var in info.variables.values():
        if not any(vr in sizes for vr in var.dimension_vrs if vr is not None):
            continue
        dims = tuple(
            sizes[vr] if vr is not None and vr in sizes else n
            for n, vr in zip(var.dimensions, var.dimension_vrs)
        )
        if dims != var.dimensions:
            # a declared start of the old length no longer applies: its elements have none
            start = var.start if _count(var.start) in (1, math.prod(dims)) else None
            changed[var.name] = dataclasses.replace(var, dimensions=dims, start=start)
    if not changed:
        return info
    derivatives = [d.variable.name for d in info.raw.derivatives] if info.raw is not None else []
    states = info.number_of_states + sum(
        changed[name].size - info.variables[name].size for name in derivatives if name in changed
    )
    return dataclasses.replace(info, variables={**info.variables, **changed}, number_of_states=states)


def _count(start: Any) -> int:
    if isinstance(start, str):
        return len(start.split())
    return len(start) if isinstance(start, list | tuple) else 1


def sizes_of(values: Mapping[Variable, int]) -> dict[int, int]:
    """Value reference -> size, for :func:`resized`."""
    return {var.value_reference: int(value) for var, value in values.items()}


def integer_structural(info: ModelInfo) -> list[Variable]:
    """The structural parameters the model reads back after configuration mode (the integer ones)."""
    return [v for v in structural(info) if v.type in _INTEGERS]


def refused(info: ModelInfo, values: Mapping[Variable, int], actual: Mapping[int, int]) -> str | None:
    """What is wrong where the FMU reports other values than those set in configuration mode."""
    wrong = {v.name: (want, actual.get(v.value_reference)) for v, want in values.items()}
    wrong = {name: pair for name, pair in wrong.items() if pair[0] != pair[1]}
    if not wrong:
        return None
    return f"{info.model_name}: after configuration mode the FMU reports structural parameters " + ", ".join(
        f"{name} = {got} (set {want})" for name, (want, got) in wrong.items()
    )
