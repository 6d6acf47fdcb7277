"""SSP 1.0 system structure: ``.ssp`` archives and ``.ssd`` files, read with ``xml.etree``.

Why not a library: ``pyssp-standard`` (PyPI) is marked alpha and brings ``xmlschema`` and ``pint``
for what is here a read of a handful of elements, and FMPy's own SSD reader would pull the FMU
runtime into a module that only describes. What is read: the top-level system's components
(``ssd:Component`` with an FMU ``source`` and its ``implementation``), their connectors' units,
connections between components with their transformation (``ssc:LinearTransformation``,
``ssc:BooleanMappingTransformation``, ``ssc:IntegerMappingTransformation``,
``ssc:EnumerationMappingTransformation``) and ``suppressUnitConversion``, the unit definitions
(``ssd:Units``), parameter bindings given inline (``ssd:ParameterValues``) or as ``.ssv`` files, and
the default experiment. What this reader cannot honour is refused, naming the element, the file
and the reason, never skipped: nested systems, signal dictionaries and their references,
parameter mappings (``.ssm``), components that are not FMUs, parameter bindings of another type, a
transformation on a connection to the system's own connectors. Annotations and geometry are
ignored, as the standard allows.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.plant.system.osp import is_osp_file, read_osp
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
    _refuse_unread(system, origin)
    components = {}
    for element in _children(system, "Elements"):
        component = _component(element, root, origin)
        components[component.name] = component
    for name, value in _bindings(system, root, origin).items():
        comp, _, var = name.partition(".")
        if comp not in components or not var:
            raise ConfigError(
                f"parameter binding {name!r} of the system names no component.variable; "
                f"components: {list(components)} [{origin}]"
            )
        components[comp].parameters[var] = value
    connections = tuple(_connections(system, components, origin))
    step, duration = None, None
    experiment = top.find(f"{SSD}DefaultExperiment")
    if experiment is not None:
        for annotation in experiment.iter():  # a tool's annotation (OSP: baseStepSize)
            for key in ("stepSize", "baseStepSize"):
                if key in annotation.attrib:
                    step = _float(annotation.attrib[key], key, origin)
        if "stopTime" in experiment.attrib:
            start = _float(experiment.attrib.get("startTime", "0"), "startTime", origin)
            duration = _float(experiment.attrib["stopTime"], "stopTime", origin) - start
    return SystemDescription(
        components=components,
        connections=connections,
        step_size_s=step,
        source=origin,
        units=_units(top, origin),
        duration_s=duration,
    )


def _float(text: str, key: str, origin: Path) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"ssd:DefaultExperiment: {key}={text!r} is not a number [{origin}]") from None


def ssp_experiment(
    path: Path, *, step_size_s: float | None = None, duration_s: float | None = None
) -> Experiment:
    """An experiment that runs the system of ``path`` (an .ssp/.ssd) as it is: no actions, every
    numeric output of every component observed, the macro step and duration of its
    DefaultExperiment unless given."""
    from bridge.experiment.config import parse_experiment
    from bridge.fmu import read_model_info

    system = read_ssp(path)
    step = step_size_s or system.step_size_s
    if step is None:
        raise ConfigError(
            f"{path.name} gives no step size (ssd:DefaultExperiment annotation stepSize or OSP's "
            f"baseStepSize); pass --step-size SECONDS [{path}]"
        )
    outputs = [
        f"{name}.{element}"
        for name, component in system.components.items()
        for var in read_model_info(component.fmu).by_causality("output")
        if var.is_numeric
        for element in var.element_names()
    ]
    duration = duration_s or system.duration_s or step
    data = {
        "name": path.stem,
        "model": {"fmu": str(path), "step_size": step, "episode_duration": _whole(duration, step)},
        "observations": {"outputs": outputs, "scale": "none"},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=path)


def _whole(duration_s: float, step_s: float) -> float:
    """``duration_s`` rounded to whole macro steps (at least one)."""
    return max(1, round(duration_s / step_s)) * step_s


def _refuse_unread(system: ET.Element, origin: Path) -> None:
    """Elements of a system this reader does not implement: refused by name, never skipped."""
    name = system.attrib.get("name", "?")
    if system.find(f"{SSD}SignalDictionaries") is not None:
        raise ConfigError(
            f"system {name!r}: ssd:SignalDictionaries are not supported (signal dictionaries pass "
            f"signals through dictionary entries, which this master does not route); connect the "
            f"components' connectors directly [{origin}]"
        )


def _units(top: ET.Element, origin: Path) -> dict[str, Unit]:
    units = {}
    for unit in _children(top, "Units"):
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


def _component(element: ET.Element, root: Path, origin: Path) -> Component:
    name = element.attrib.get("name", "?")
    if element.tag == f"{SSD}System":
        raise ConfigError(f"nested system {name!r}: only flat systems of FMUs are supported [{origin}]")
    if element.tag == f"{SSD}SignalDictionaryReference":
        raise ConfigError(
            f"element {name!r}: ssd:SignalDictionaryReference is not supported (signal dictionaries "
            f"are not routed by this master); connect the components' connectors directly [{origin}]"
        )
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
    parameters = _bindings(element, root, origin)
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


def _bindings(element: ET.Element, root: Path, origin: Path) -> dict[str, Any]:
    values: dict[str, Any] = {}
    owner = f"{_local(element.tag)} {element.attrib.get('name', '?')!r}"
    for binding in _children(element, "ParameterBindings"):
        if binding.find(f"{SSD}ParameterMapping") is not None:
            raise ConfigError(
                f"{owner}: ssd:ParameterMapping (an .ssm parameter mapping) is not supported: the "
                f"mapped names and transformations would not reach the FMU; bind the values under "
                f"the FMU's own names (ssd:ParameterValues or an .ssv file) [{origin}]"
            )
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
        for parameter in parameter_set.iter(f"{SSV}Parameter"):
            name = parameter.attrib["name"].removeprefix(prefix)
            values[name] = _value(parameter, name, origin)
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


def _connections(system: ET.Element, components: dict[str, Component], origin: Path) -> list[Connection]:
    found = []
    for element in _children(system, "Connections"):
        a, b = element.attrib.get("startElement"), element.attrib.get("endElement")
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
        for side in (a, b):
            if side not in components:
                raise ConfigError(
                    f"connection {text}: {side!r} is not a component; "
                    f"components: {list(components)} [{origin}]"
                )
        suppress = element.attrib.get("suppressUnitConversion", "false").lower() in ("true", "1")
        found.append(
            Connection(
                Endpoint(a, element.attrib["startConnector"]),
                Endpoint(b, element.attrib["endConnector"]),
                transform,
                suppress,
            )
        )
    return found


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
