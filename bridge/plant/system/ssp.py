"""SSP 1.0 system structure: ``.ssp`` archives and ``.ssd`` files, read with ``xml.etree``.

Why not a library: ``pyssp-standard`` (PyPI) is marked alpha and brings ``xmlschema`` and ``pint``
for what is here a read of a handful of elements, and FMPy's own SSD reader would pull the FMU
runtime into a module that only describes. What is read: the system's components (``ssd:Component``
with an FMU ``source`` and its ``implementation``), nested systems (flattened: ``system/component``),
their connectors' units, connections with their transformation (``ssc:LinearTransformation``,
``ssc:BooleanMappingTransformation``, ``ssc:IntegerMappingTransformation``,
``ssc:EnumerationMappingTransformation``) and ``suppressUnitConversion``, the unit definitions
(``ssd:Units``, ``ssv:Units``), parameter bindings given inline (``ssd:ParameterValues``) or as
``.ssv`` files, with units, parameter mappings (inline or ``.ssm``: :mod:`.ssm`), signal
dictionaries and the connections through their references and through nested systems' connectors
(:mod:`.ssb`), and the default experiment. What this reader cannot honour is refused, naming the
element, the file and the reason, never skipped: components that are not FMUs, parameter bindings
of another type, a transformation on a connection to the top system's own connectors.
Annotations and geometry are ignored, as the standard allows.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.plant.system.osp import is_osp_file, read_osp
from bridge.plant.system.ssb import Bus, read_dictionaries
from bridge.plant.system.ssm import apply, read_mapping
from bridge.plant.system.structure import (
    Component,
    Connection,
    Endpoint,
    SystemDescription,
    Transform,
    Unit,
)

SSD = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
SSV = "{http://ssp-standard.org/SSP1/SystemStructureParameterValues}"
SSC = "{http://ssp-standard.org/SSP1/SystemStructureCommon}"
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_TRANSFORMS = (
    "LinearTransformation",
    "BooleanMappingTransformation",
    "IntegerMappingTransformation",
    "EnumerationMappingTransformation",
)
_IMPLEMENTATION = {"any": "auto", "CoSimulation": "cs", "ModelExchange": "me"}
_TYPES: dict[str, Callable[[str], Any]] = {
    "Real": float,
    "Integer": int,
    "Boolean": lambda v: v.lower() in ("true", "1"),
    "String": str,
}


@dataclass
class _Read:
    """What the reading collects beyond the description: units of bound values, unit definitions."""

    definitions: dict[str, Unit]
    value_units: dict[str, dict[str, str]] = field(default_factory=dict)  # component -> name -> unit


def read_ssp(path: Path) -> SystemDescription:
    """The system of an ``.ssp`` archive (``SystemStructure.ssd`` inside), an ``.ssd`` file, or
    OSP's ``OspSystemStructure.xml`` (:mod:`bridge.plant.system.osp`)."""
    if is_osp_file(path):
        return read_osp(path)
    if path.suffix.lower() == ".ssp":
        root = _extract(path)
        ssd = root / "SystemStructure.ssd"
        if not ssd.exists():
            raise ConfigError(
                f"{path.name} has no SystemStructure.ssd at its root; not an SSP archive [{path}]"
            )
        return _read_ssd(ssd, root, path)
    return _read_ssd(path, path.parent, path)


def _extract(path: Path) -> Path:
    target = Path(tempfile.mkdtemp(prefix="fmu-bridge-ssp-"))
    atexit.register(shutil.rmtree, target, True)
    try:
        with zipfile.ZipFile(path) as archive:
            archive.extractall(target)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ConfigError(f"cannot open the SSP archive: {exc} [{path}]") from exc
    return target


def _read_ssd(ssd: Path, root: Path, origin: Path) -> SystemDescription:
    try:
        tree = ET.parse(ssd)
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"cannot read the system structure: {exc} [{origin}]") from exc
    top = tree.getroot()
    system = top.find(f"{SSD}System")
    if system is None:
        raise ConfigError(f"{ssd.name}: no ssd:System element; is this an SSP 1.0 file? [{origin}]")
    found = _Read(_units(top, origin))
    bus = Bus({})
    components: dict[str, Component] = {}
    connections = tuple(_read_system(system, "", root, origin, found, bus, components) + bus.routed(origin))
    _convert_bound_values(components, found, origin)
    step, duration, start = None, None, None
    experiment = top.find(f"{SSD}DefaultExperiment")
    if experiment is not None:
        for annotation in experiment.iter():  # a tool's annotation (OSP: baseStepSize)
            for key in ("stepSize", "baseStepSize"):
                if key in annotation.attrib:
                    step = _float(annotation.attrib[key], key, origin)
        if "startTime" in experiment.attrib:
            start = _float(experiment.attrib["startTime"], "startTime", origin)
        if "stopTime" in experiment.attrib:
            duration = _float(experiment.attrib["stopTime"], "stopTime", origin) - (start or 0.0)
    return SystemDescription(
        components=components,
        connections=connections,
        step_size_s=step,
        source=origin,
        units=found.definitions,
        duration_s=duration,
        start_time_s=start,
    )


def _read_system(  # noqa: PLR0917 (one recursive reader)
    system: ET.Element,
    prefix: str,
    root: Path,
    origin: Path,
    found: _Read,
    bus: Bus,
    components: dict[str, Component],
) -> list[Connection]:
    """The components of ``system`` into ``components`` and its direct connections; a nested
    system's components are named ``system/component`` and its connectors route like a signal
    dictionary's entries (:class:`.ssb.Bus`)."""
    bus.dictionaries.update(read_dictionaries(system, root, origin))
    connections: list[Connection] = []
    for element in _children(system, "Elements"):
        name = prefix + element.attrib.get("name", "?")
        if element.tag == f"{SSD}SignalDictionaryReference":
            bus.add_reference(element, origin, prefix)
        elif element.tag == f"{SSD}System":
            connectors = [c.attrib.get("name", "") for c in _children(element, "Connectors")]
            bus.add_system(name, connectors)
            connections += _read_system(element, f"{name}/", root, origin, found, bus, components)
        else:
            component = _component(element, root, origin, found, prefix)
            components[component.name] = component
    _system_bindings(system, prefix, root, origin, found, components)
    return connections + _connections(system, components, bus, origin, prefix)


def _system_bindings(  # noqa: PLR0917
    system: ET.Element, prefix: str, root: Path, origin: Path, found: _Read, components: dict[str, Component]
) -> None:
    """A system's own parameter bindings: ``component.variable`` of its components."""
    units: dict[str, str] = {}
    for name, value in _bindings(system, root, origin, found, units).items():
        comp, _, var = name.partition(".")
        comp = prefix + comp
        if comp not in components or not var:
            raise ConfigError(
                f"parameter binding {name!r} of system {system.attrib.get('name', '?')!r} names no "
                f"component.variable; components: {list(components)} [{origin}]"
            )
        components[comp].parameters[var] = value
        if name in units:
            found.value_units.setdefault(comp, {})[var] = units[name]


def _float(text: str, key: str, origin: Path) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"ssd:DefaultExperiment: {key}={text!r} is not a number [{origin}]") from None


def _convert_bound_values(components: dict[str, Component], found: _Read, origin: Path) -> None:
    """Bound values given in another unit than their variable's, converted (SSP's unit rules)."""
    from bridge.fmu import read_model_info
    from bridge.plant.system.transform import convert_value

    for name, units in found.value_units.items():
        component = components[name]
        info = read_model_info(component.fmu)
        for var_name, unit in units.items():
            var = info.variables.get(var_name)
            if var is None:
                continue  # check_system names the unknown parameter
            what = f"component {name!r}: parameter binding {var_name!r}"
            try:
                value = convert_value(
                    float(component.parameters[var_name]), unit, var, info, found.definitions, what=what
                )
            except ConfigError as exc:
                raise ConfigError(f"{exc} [{origin}]") from None
            component.parameters[var_name] = value


def _units(top: ET.Element, origin: Path, ns: str = SSD) -> dict[str, Unit]:
    units = {}
    box = top.find(f"{ns}Units")
    for unit in list(box) if box is not None else []:
        base = unit.find(f"{SSC}BaseUnit")
        name = unit.attrib.get("name", "")
        if base is None or not name:
            raise ConfigError(f"ssc:Unit {name!r}: a unit needs a name and an ssc:BaseUnit [{origin}]")
        try:
            exponents = tuple(int(base.attrib.get(b, "0")) for b in _BASE_UNITS)
            factor = float(base.attrib.get("factor", "1"))
            offset = float(base.attrib.get("offset", "0"))
        except ValueError as exc:
            raise ConfigError(f"ssc:Unit {name!r}: {exc}; exponents are integers [{origin}]") from exc
        units[name] = Unit(name, exponents, factor, offset)
    return units


def _children(element: ET.Element, container: str) -> list[ET.Element]:
    box = element.find(f"{SSD}{container}")
    return list(box) if box is not None else []


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _component(element: ET.Element, root: Path, origin: Path, found: _Read, prefix: str = "") -> Component:
    name = prefix + element.attrib.get("name", "?")
    if element.tag != f"{SSD}Component":
        raise ConfigError(f"element {name!r} ({element.tag}) is not an ssd:Component [{origin}]")
    kind = element.attrib.get("type", "application/x-fmu-sharedlibrary")
    if kind != "application/x-fmu-sharedlibrary":
        raise ConfigError(f"component {name!r} has type {kind!r}; only FMUs are supported [{origin}]")
    source = element.attrib.get("source", "")
    fmu = root / source
    if not source or not fmu.exists():
        inside = "in the SSP archive" if origin.suffix.lower() == ".ssp" else f"next to {origin.name}"
        raise ConfigError(
            f"component {name!r}: its FMU {source!r} is missing {inside}; add the file or fix the "
            f"component's source attribute [{origin}]"
        )
    value_units: dict[str, str] = {}
    parameters = _bindings(element, root, origin, found, value_units)
    if value_units:
        found.value_units[name] = value_units
    implementation = element.attrib.get("implementation", "any")
    if implementation not in _IMPLEMENTATION:
        raise ConfigError(
            f"component {name!r}: implementation {implementation!r} is not one of "
            f"{list(_IMPLEMENTATION)} [{origin}]"
        )
    return Component(
        name=name,
        fmu=fmu,
        parameters=parameters,
        interface=_IMPLEMENTATION[implementation],  # type: ignore[arg-type]
        connector_units=_connector_units(element),
    )


def _connector_units(element: ET.Element) -> dict[str, str]:
    units = {}
    for connector in _children(element, "Connectors"):
        for typed in connector:
            if typed.tag.startswith(SSC) and typed.attrib.get("unit"):
                units[connector.attrib.get("name", "")] = typed.attrib["unit"]
    return units


def _bindings(
    element: ET.Element, root: Path, origin: Path, found: _Read, units: dict[str, str]
) -> dict[str, Any]:
    """The bound values by name; ``units`` receives the unit of each value that declares one, and
    ``found`` the unit definitions of the parameter sets."""
    values: dict[str, Any] = {}
    owner = f"{_local(element.tag)} {element.attrib.get('name', '?')!r}"
    for binding in _children(element, "ParameterBindings"):
        mapping = read_mapping(binding, root, origin, owner, _transform)
        kind = binding.attrib.get("type", "application/x-ssp-parameter-set")
        if kind != "application/x-ssp-parameter-set":
            raise ConfigError(
                f"{owner}: a parameter binding of type {kind!r} is not supported; only SSP parameter "
                f"sets (application/x-ssp-parameter-set, .ssv) are read [{origin}]"
            )
        prefix = binding.attrib.get("prefix", "")
        inline = binding.find(f"{SSD}ParameterValues")
        if inline is not None:
            parameter_set = inline.find(f"{SSV}ParameterSet")
        elif "source" in binding.attrib:
            parameter_set = _read_ssv(root / binding.attrib["source"], origin)
        else:
            continue
        if parameter_set is None:
            continue
        names = set()
        for parameter in parameter_set.iter(f"{SSV}Parameter"):
            full = parameter.attrib["name"]
            names.add(full)
            value = _value(parameter, full, origin)
            real = parameter.find(f"{SSV}Real")
            unit = real.attrib.get("unit") if real is not None else None
            if mapping is not None and full in mapping:
                name, value, unit = apply(mapping[full], full, value, unit, where=(owner, origin))
            else:
                name = full.removeprefix(prefix)
            values[name] = value
            if unit:
                units[name] = unit
        unknown = sorted(set(mapping or {}) - names)
        if unknown:
            raise ConfigError(
                f"{owner}: parameter mapping entries {unknown} name no parameter of the parameter set "
                f"{parameter_set.attrib.get('name', '')!r}; parameters: {sorted(names)} [{origin}]"
            )
        found.definitions.update(_units(parameter_set, origin, SSV))
    return values


def _read_ssv(path: Path, origin: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"cannot read the parameter values {path.name}: {exc} [{origin}]") from exc


def _value(parameter: ET.Element, name: str, origin: Path) -> Any:
    for kind, convert in _TYPES.items():
        typed = parameter.find(f"{SSV}{kind}")
        if typed is not None:
            return convert(typed.attrib["value"])
    raise ConfigError(f"parameter {name!r}: no Real, Integer, Boolean or String value [{origin}]")


def _connections(
    system: ET.Element, components: dict[str, Component], bus: Bus, origin: Path, prefix: str = ""
) -> list[Connection]:
    """The connections of ``system``; those through signal dictionaries and nested systems' own
    connectors go to ``bus``, which routes them. A connection to the top system's own connectors
    is left out (the task reaches the component's variable by name)."""
    found = []
    for element in _children(system, "Connections"):
        a, b = _element_name(element, "start", prefix), _element_name(element, "end", prefix)
        y, u = element.attrib.get("startConnector"), element.attrib.get("endConnector")
        text = f"{a or ''}.{y} -> {b or ''}.{u}"
        transform = _transform(element, text, origin)
        if not a or not b:
            if transform is not None:
                raise ConfigError(
                    f"connection {text}: a transformation on a connection to the system's own "
                    f"connectors is not supported (the task sets component inputs directly); move "
                    f"it to a connection between components [{origin}]"
                )
            continue  # a system-level connector: the variables are reached as component.variable
        suppress = element.attrib.get("suppressUnitConversion", "false").lower() in ("true", "1")
        connection = Connection(Endpoint(a, y or ""), Endpoint(b, u or ""), transform, suppress)
        if bus.add(connection, origin):
            continue  # through a signal dictionary: routed below
        for side in (a, b):
            if side not in components:
                raise ConfigError(
                    f"connection {text}: {side!r} is not a component; "
                    f"components: {list(components)} [{origin}]"
                )
        found.append(connection)
    return found


def _element_name(connection: ET.Element, end: str, prefix: str) -> str | None:
    """The flat name of a connection end's element; a nested system's own connector: the system."""
    name = connection.attrib.get(f"{end}Element")
    if name:
        return prefix + name
    return prefix[:-1] or None  # "" at the top: the system's own connector


def _transform(element: ET.Element, text: str, origin: Path) -> Transform | None:
    """The connection's ``ssc:*Transformation``, if it has one."""
    found = [child for child in element if child.tag.startswith(SSC) and "Transformation" in child.tag]
    if not found:
        return None
    child = found[0]
    kind = _local(child.tag)
    if kind not in _TRANSFORMS or len(found) > 1:
        raise ConfigError(
            f"connection {text}: ssc:{kind} is not an SSP 1.0 transformation (or there is more than "
            f"one); expected one of {list(_TRANSFORMS)} [{origin}]"
        )
    if kind == "LinearTransformation":
        try:
            factor = float(child.attrib.get("factor", "1"))
            offset = float(child.attrib.get("offset", "0"))
        except ValueError as exc:
            raise ConfigError(f"connection {text}: ssc:LinearTransformation: {exc} [{origin}]") from exc
        return Transform("LinearTransformation", factor=factor, offset=offset)
    entries = []
    for entry in child.iter(f"{SSC}MapEntry"):
        if "source" not in entry.attrib or "target" not in entry.attrib:
            raise ConfigError(f"connection {text}: ssc:{kind}: a MapEntry needs source and target [{origin}]")
        entries.append((entry.attrib["source"], entry.attrib["target"]))
    if not entries:
        raise ConfigError(f"connection {text}: ssc:{kind} has no ssc:MapEntry [{origin}]")
    return Transform(kind, entries=tuple(entries))  # type: ignore[arg-type]
