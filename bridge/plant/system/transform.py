"""What a value undergoes as it crosses a connection: unit conversion, then the SSP transformation.

SSP 1.0 (``SystemStructureCommon``, ``GTransformationChoice``) fixes the order: the source value is
first converted to the target connector's unit (unless the connection says
``suppressUnitConversion``), then transformed. ``LinearTransformation`` gives ``factor * value +
offset`` and applies to continuous (float) connectors; ``BooleanMappingTransformation`` maps
booleans, ``IntegerMappingTransformation`` integers and enumerations by value,
``EnumerationMappingTransformation`` enumerations by item name, each through its ``MapEntry``
table. The standard does not say what becomes of a value the table does not list; here it passes
unchanged (documented in docs/systems.md).

Units: a connector's unit is the SSD's (``unit`` on its type) or else the FMU variable's; a unit's
definition is the SSD's ``ssd:Units`` or else the FMU's ``UnitDefinitions``. Both sides declared and
defined with the same SI base units: converted (``value_SI = factor * value + offset`` on each
side). Different base units: refused. Different names of which one is not defined anywhere: a
warning, values pass unconverted (the names alone do not say whether ``1/min`` and ``rpm`` agree).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from bridge.errors import ConfigError
from bridge.fmu.vocab import ModelInfo, Variable
from bridge.plant.system.structure import Connection, SystemDescription, Transform, Unit

Convert = Callable[[float], float]
_FLOATS = ("Float32", "Float64")
_INTEGERS = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Enumeration")
_BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


@dataclass(frozen=True)
class Affine:
    """A linear transformation and/or unit conversion as one map, ``factor * value + offset``: the
    expression the native master's C loop computes for the link too (``master.c``), so both
    masters give the same value bit for bit."""

    factor: float
    offset: float = 0.0

    def __call__(self, value: float) -> float:
        return self.factor * value + self.offset

    def then(self, other: Affine) -> Affine:
        """``other`` applied after this map, as one map."""
        return Affine(other.factor * self.factor, other.factor * self.offset + other.offset)


@dataclass(frozen=True)
class Coupling:
    """How one connection carries its value: ``convert`` None passes it unchanged."""

    convert: Convert | None
    warning: str = ""


def coupling(
    c: Connection,
    source: Variable,
    target: Variable,
    infos: Mapping[str, ModelInfo],
    system: SystemDescription,
) -> Coupling:
    """The unit conversion and transformation of ``c`` composed, checked against both variables."""
    units, warning = _unit_conversion(c, source, target, infos, system)
    transform = _transformation(c, source, target, system)
    if units is None:
        return Coupling(transform, warning)
    if transform is None:
        return Coupling(units, warning)
    if isinstance(units, Affine) and isinstance(transform, Affine):
        return Coupling(units.then(transform), warning)
    first, then = units, transform
    return Coupling(lambda y: then(first(y)), warning)


def _where(system: SystemDescription) -> str:
    if system.ssp is not None and system.ssp != system.source:
        return f" [{system.ssp}; {system.source}]"
    return system.where


def connection_units(
    c: Connection, source: Variable, target: Variable, system: SystemDescription
) -> tuple[str, str] | None:
    """The units a connection converts between (source's, target's), None where it converts none."""
    a, b = _unit_name(c, "source", source, system), _unit_name(c, "target", target, system)
    return None if not a or not b or a == b or c.suppress_units else (a, b)


def describe(c: Connection, convert: Convert | None) -> str:
    """What a value undergoes on ``c``, for a person: unchanged, an affine map, or a table."""
    if convert is None:
        return "unchanged"
    if isinstance(convert, Affine):
        return f"{convert.factor!r} * value + {convert.offset!r}"
    t = c.transform
    return f"table ({t.kind}, {len(t.entries)} entries)" if t else "a mapping"


def _unit_name(c: Connection, end: str, var: Variable, system: SystemDescription) -> str | None:
    endpoint = c.source if end == "source" else c.target
    component = system.components.get(endpoint.component)
    declared = component.connector_units.get(endpoint.variable) if component else None
    return declared or var.unit


def _definition(
    name: str, component: str, infos: Mapping[str, ModelInfo], system: SystemDescription
) -> Unit | None:
    return unit_definition(name, infos[component], system.units)


def unit_definition(name: str, info: ModelInfo, units: Mapping[str, Unit]) -> Unit | None:
    """The definition of unit ``name``: the SSD's (``units``), else the FMU's UnitDefinitions."""
    if name in units:
        return units[name]
    raw = getattr(info, "raw", None)
    for unit in getattr(raw, "unitDefinitions", None) or ():
        if unit.name == name and unit.baseUnit is not None:
            base = unit.baseUnit
            return Unit(name, tuple(int(getattr(base, b, 0) or 0) for b in _BASE), base.factor, base.offset)
    return None


def convert_value(
    value: float, unit: str, var: Variable, info: ModelInfo, units: Mapping[str, Unit], *, what: str
) -> float:
    """``value`` given in ``unit`` as a value of ``var`` in its own unit (a parameter binding);
    refused where the units measure different quantities or one has no definition."""
    if not var.unit or var.unit == unit:
        return value
    given, own = unit_definition(unit, info, units), unit_definition(var.unit, info, units)
    if given is None or own is None:
        missing = [n for n, u in ((unit, given), (var.unit, own)) if u is None]
        raise ConfigError(
            f"{what}: the value is in {unit!r} and {var.name} of {info.model_name} in {var.unit!r}, and "
            f"{missing} has no definition (ssd:Units, ssv:Units or the FMU's UnitDefinitions); define "
            f"it or give the value in {var.unit!r}"
        )
    if given.base != own.base:
        raise ConfigError(
            f"{what}: the value is in {unit!r} ({_dimension(given)}) and {var.name} of {info.model_name} "
            f"in {var.unit!r} ({_dimension(own)}): different quantities; give the value in {var.unit!r}"
        )
    return (given.factor * value + given.offset - own.offset) / own.factor


def _unit_conversion(
    c: Connection,
    source: Variable,
    target: Variable,
    infos: Mapping[str, ModelInfo],
    system: SystemDescription,
) -> tuple[Convert | None, str]:
    a, b = _unit_name(c, "source", source, system), _unit_name(c, "target", target, system)
    if not a or not b or a == b or c.suppress_units:
        return None, ""
    ua = _definition(a, c.source.component, infos, system)
    ub = _definition(b, c.target.component, infos, system)
    if ua is None or ub is None:
        missing = [n for n, u in ((a, ua), (b, ub)) if u is None]
        return None, (
            f"connection {c}: unit {a!r} of {c.source} differs from {b!r} of {c.target} and {missing} "
            f"has no definition (ssd:Units or the FMU's UnitDefinitions); values pass unconverted"
            f"{_where(system)}"
        )
    if ua.base != ub.base:
        raise ConfigError(
            f"connection {c}: unit {a!r} of {c.source} ({_dimension(ua)}) and {b!r} of {c.target} "
            f"({_dimension(ub)}) measure different quantities; connect variables of one quantity, or "
            f'set suppressUnitConversion="true" on the connection if the values are meant to pass as '
            f"they are{_where(system)}"
        )
    if ua.factor == ub.factor and ua.offset == ub.offset:
        return None, ""
    # value_SI = fa * y + oa = fb * u + ob, solved for u
    return Affine(ua.factor / ub.factor, (ua.offset - ub.offset) / ub.factor), ""


def _dimension(unit: Unit) -> str:
    parts = [f"{b}^{e}" if e != 1 else b for b, e in zip(_BASE, unit.base) if e]
    return " ".join(parts) or "dimensionless"


def _transformation(
    c: Connection, source: Variable, target: Variable, system: SystemDescription
) -> Convert | None:
    t = c.transform
    if t is None:
        return None
    where = _where(system)
    if t.kind == "LinearTransformation":
        _require(c, t, (source, target), _FLOATS, "continuous (Float) connectors", where)
        return Affine(t.factor, t.offset)
    if t.kind == "BooleanMappingTransformation":
        _require(c, t, (source, target), ("Boolean",), "Boolean connectors", where)
        flags = {_boolean(s, c, t, where): _boolean(v, c, t, where) for s, v in t.entries}
        return _lookup({float(k): float(v) for k, v in flags.items()})
    if t.kind == "IntegerMappingTransformation":
        _require(c, t, (source, target), _INTEGERS, "Integer and Enumeration connectors", where)
        return _lookup(
            {float(_integer(s, c, t, where)): float(_integer(v, c, t, where)) for s, v in t.entries}
        )
    _require(c, t, (source, target), ("Enumeration",), "Enumeration connectors", where)
    names_in, names_out = dict(source.enum_items), dict(target.enum_items)
    table: dict[float, float] = {}
    for s, v in t.entries:
        for name, items, end in ((s, names_in, c.source), (v, names_out, c.target)):
            if name not in items:
                raise ConfigError(
                    f"connection {c}: ssc:{t.kind}: {name!r} is not an item of {end}'s enumeration "
                    f"{source.declared_type if end is c.source else target.declared_type!r}; items: "
                    f"{list(items)}{where}"
                )
        table[float(names_in[s])] = float(names_out[v])
    return _lookup(table)


def _lookup(table: dict[float, float]) -> Convert:
    return lambda y: table.get(y, y)


def _require(  # noqa: PLR0917 (one check, all of it named in the message)
    c: Connection,
    t: Transform,
    ends: tuple[Variable, Variable],
    types: tuple[str, ...],
    what: str,
    where: str,
) -> None:
    for var, end in zip(ends, (c.source, c.target)):
        if var.type not in types:
            raise ConfigError(
                f"connection {c}: ssc:{t.kind} applies to {what}, and {end} is {var.type}; use the "
                f"transformation of its type (LinearTransformation for Float, IntegerMapping for "
                f"Integer, BooleanMapping for Boolean, EnumerationMapping for Enumeration){where}"
            )


def _boolean(text: str, c: Connection, t: Transform, where: str) -> bool:
    if text.strip() in ("true", "1"):
        return True
    if text.strip() in ("false", "0"):
        return False
    raise ConfigError(f"connection {c}: ssc:{t.kind}: MapEntry value {text!r} is not an xs:boolean{where}")


def _integer(text: str, c: Connection, t: Transform, where: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ConfigError(
            f"connection {c}: ssc:{t.kind}: MapEntry value {text!r} is not an integer{where}"
        ) from None
