"""SSP 1.0 system structure: ``.ssp`` archives and ``.ssd`` files, read with ``xml.etree``.

Why not a library: ``pyssp-standard`` (PyPI) is marked alpha and brings ``xmlschema`` and ``pint``
for what is here a read of a handful of elements, and FMPy's own SSD reader would pull the FMU
runtime into a module that only describes. What is read: the top-level system's components
(``ssd:Component`` with an FMU ``source``), their connectors' kinds, connections between
components, parameter bindings given inline (``ssd:ParameterValues``) or as ``.ssv`` files, and the
default experiment. Nested systems, signal dictionaries and parameter mappings are refused with
a clear error rather than half-read.
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
from bridge.plant.system.description import Component, Connection, Endpoint, SystemDescription

SSD = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
SSV = "{http://ssp-standard.org/SSP1/SystemStructureParameterValues}"
SSC = "{http://ssp-standard.org/SSP1/SystemStructureCommon}"
_TYPES: dict[str, Callable[[str], Any]] = {
    "Real": float,
    "Integer": int,
    "Boolean": lambda v: v.lower() in ("true", "1"),
    "String": str,
}


def read_ssp(path: Path) -> SystemDescription:
    """The system of an ``.ssp`` archive (``SystemStructure.ssd`` inside) or an ``.ssd`` file."""
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
    step = None
    experiment = top.find(f"{SSD}DefaultExperiment")
    if experiment is not None:
        for annotation in experiment.iter():
            if "stepSize" in annotation.attrib:
                step = float(annotation.attrib["stepSize"])
    return SystemDescription(components=components, connections=connections, step_size_s=step, source=origin)


def _children(element: ET.Element, container: str) -> list[ET.Element]:
    box = element.find(f"{SSD}{container}")
    return list(box) if box is not None else []


def _component(element: ET.Element, root: Path, origin: Path) -> Component:
    name = element.attrib.get("name", "?")
    if element.tag == f"{SSD}System":
        raise ConfigError(f"nested system {name!r}: only flat systems of FMUs are supported [{origin}]")
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
    return Component(name=name, fmu=fmu, parameters=parameters)


def _bindings(element: ET.Element, root: Path, origin: Path) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for binding in _children(element, "ParameterBindings"):
        if binding.find(f"{SSD}ParameterMapping") is not None:
            raise ConfigError(f"parameter mappings are not supported; bind values directly [{origin}]")
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
        if not a or not b:
            continue  # a system-level connector: the variables are reached as component.variable
        text = f"{a}.{element.attrib['startConnector']} -> {b}.{element.attrib['endConnector']}"
        for side in (a, b):
            if side not in components:
                raise ConfigError(
                    f"connection {text}: {side!r} is not a component; "
                    f"components: {list(components)} [{origin}]"
                )
        found.append(
            Connection(
                Endpoint(a, element.attrib["startConnector"]), Endpoint(b, element.attrib["endConnector"])
            )
        )
    return found
