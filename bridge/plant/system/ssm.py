"""SSP parameter mappings (``ssd:ParameterMapping``, inline or an ``.ssm`` file).

A parameter binding's mapping renames the parameters of its parameter set (``ssm:MappingEntry``
``source``: the name in the set, ``target``: the name in the component) and may transform their
values (``ssc:LinearTransformation`` for Real values, ``ssc:BooleanMappingTransformation``,
``ssc:IntegerMappingTransformation``). A parameter no entry names is bound by its own name (the
binding's ``prefix`` stripped), as without a mapping. Refused by name: an entry whose source is no
parameter of the set, ``EnumerationMappingTransformation`` (enumeration values in parameter sets are
not read), and a transformation of a value that declares a unit without ``suppressUnitConversion``
(SSP converts units before transforming, which needs the target's unit: bind the value in the
target's unit, or suppress the conversion).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.plant.system.structure import Transform

SSD = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
SSM = "{http://ssp-standard.org/SSP1/SystemStructureParameterMapping}"
ReadTransform = Callable[[ET.Element, str, Path], Transform | None]


@dataclass(frozen=True)
class Entry:
    """Where a parameter of the set goes, and what its value undergoes."""

    target: str
    transform: Transform | None
    suppress_units: bool


def read_mapping(
    binding: ET.Element, root: Path, origin: Path, owner: str, transform_of: ReadTransform
) -> dict[str, Entry] | None:
    """The binding's mapping by source name, or None without one."""
    mapping = binding.find(f"{SSD}ParameterMapping")
    if mapping is None:
        return None
    kind = mapping.attrib.get("type", "application/x-ssp-parameter-mapping")
    if kind != "application/x-ssp-parameter-mapping":
        raise ConfigError(f"{owner}: a parameter mapping of type {kind!r} is not supported [{origin}]")
    content = mapping.find(f"{SSM}ParameterMapping")
    if content is None and "source" in mapping.attrib:
        content = _read_ssm(root / mapping.attrib["source"], origin)
    if content is None:
        raise ConfigError(f"{owner}: ssd:ParameterMapping has neither content nor a source [{origin}]")
    entries: dict[str, Entry] = {}
    for element in content.iter(f"{SSM}MappingEntry"):
        source, target = element.attrib.get("source", ""), element.attrib.get("target", "")
        if not source or not target:
            raise ConfigError(f"{owner}: an ssm:MappingEntry needs source and target [{origin}]")
        transform = transform_of(element, f"{owner}: parameter mapping {source} -> {target}", origin)
        if transform is not None and transform.kind == "EnumerationMappingTransformation":
            raise ConfigError(
                f"{owner}: parameter mapping {source} -> {target}: EnumerationMappingTransformation is "
                f"not supported in parameter mappings; bind the enumeration's value directly [{origin}]"
            )
        suppress = element.attrib.get("suppressUnitConversion", "false").lower() in ("true", "1")
        entries[source] = Entry(target, transform, suppress)
    return entries


def _read_ssm(path: Path, origin: Path) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"cannot read the parameter mapping {path.name}: {exc} [{origin}]") from exc
    if root.tag != f"{SSM}ParameterMapping":
        raise ConfigError(f"{path.name}: the root element is not ssm:ParameterMapping [{origin}]")
    return root


def apply(
    entry: Entry, name: str, value: Any, unit: str | None, *, where: tuple[str, Path]
) -> tuple[str, Any, str | None]:
    """The target name, value and unit of parameter ``name`` after its mapping entry
    (``where``: the binding's owner and the file, for errors)."""
    owner, origin = where
    what = f"{owner}: parameter mapping {name} -> {entry.target}"
    t = entry.transform
    if t is None:
        return entry.target, value, None if entry.suppress_units else unit
    if unit and not entry.suppress_units:
        raise ConfigError(
            f"{what}: the value is in {unit!r} and the entry transforms it; SSP converts units "
            f"first, which needs the target's unit: give the value in the target's unit, or set "
            f'suppressUnitConversion="true" on the entry [{origin}]'
        )
    if t.kind == "LinearTransformation":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(
                f"{what}: LinearTransformation applies to Real values, got {value!r} [{origin}]"
            )
        return entry.target, t.factor * float(value) + t.offset, None
    boolean = t.kind == "BooleanMappingTransformation"
    if boolean != isinstance(value, bool) or isinstance(value, (float, str)):
        raise ConfigError(f"{what}: {t.kind} does not apply to the value {value!r} [{origin}]")
    table = {_parse(s, boolean, what, origin): _parse(v, boolean, what, origin) for s, v in t.entries}
    return entry.target, table.get(value, value), None


def _parse(text: str, boolean: bool, what: str, origin: Path) -> bool | int:
    word = text.strip()
    try:
        if boolean:
            if word not in ("true", "false", "1", "0"):
                raise ValueError(word)
            return word in ("true", "1")
        return int(word)
    except ValueError:
        raise ConfigError(
            f"{what}: MapEntry value {text!r} is not a {'boolean' if boolean else 'integer'} [{origin}]"
        ) from None
