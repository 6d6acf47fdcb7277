"""OSP's ``OspSystemStructure.xml`` (libcosim's system format), read into a :class:`SystemDescription`.

What is read: ``Simulators`` (name, FMU ``source`` relative to the file, ``stepSize``,
``InitialValues`` as parameters), ``BaseStepSize``, ``StartTime``, ``VariableConnection`` (oriented
as libcosim orients it: from the end that is an output or calculated parameter), and
``LinearTransformation`` functions wired by one ``SignalConnection`` into ``in`` and one or more out
of ``out`` (each becomes a connection with that transformation, as SSP's). Refused by name: ``Sum``
and ``VectorSum`` functions, variable and signal group connections (they need the FMUs'
``OspModelDescription.xml``), simulators whose source is not a file, any ``Algorithm`` but
``fixedStep`` (ECCO's adaptive step) and power bonds.

Decimation, as libcosim's fixed-step algorithm: a simulator with ``stepSize`` steps every
``d = floor(stepSize / BaseStepSize)`` base steps (at least 1; a step that is not a whole number of
base steps is rounded down with a warning naming both, as libcosim's integer division of the two
durations does). The macro step is the largest
step, ``max(d) * BaseStepSize``; every simulator does ``max(d) / d`` steps of its own inside it (so
every ``d`` must divide the largest, else the file is refused naming the two simulators).
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.plant.system.structure import Component, Connection, Endpoint, SystemDescription, Transform

_VALUES = {"Real": float, "Integer": int, "Enumeration": int, "String": str}


def is_osp_file(path: Path) -> bool:
    """Whether ``path`` names an OSP system structure (``*OspSystemStructure*.xml``)."""
    return path.suffix.lower() == ".xml" and "ospsystemstructure" in path.name.lower()


def read_osp(path: Path) -> SystemDescription:
    """The system of an ``OspSystemStructure.xml`` file."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"cannot read the OSP system structure: {exc} [{path}]") from exc
    if _local(root.tag) != "OspSystemStructure":
        raise ConfigError(
            f"{path.name}: the root element is {_local(root.tag)}, not OspSystemStructure [{path}]"
        )
    components = {c.name: c for c in (_simulator(e, path) for e in _all(root, "Simulators", "Simulator"))}
    connections = [
        _variable_connection(e, components, path) for e in _all(root, "Connections", "VariableConnection")
    ]
    connections += _functions(root, components, path)
    for kind in ("VariableGroupConnection", "SignalGroupConnection"):
        if _all(root, "Connections", kind):
            raise ConfigError(
                f"{kind} is not supported: variable groups come from each FMU's OspModelDescription.xml, "
                f"which is not read; connect the variables one by one (VariableConnection) [{path}]"
            )
    _refuse_ecco(root, path)
    base = _number(root, "BaseStepSize", path)
    components, macro, warnings = decimate(components, base, path)
    return SystemDescription(
        components=components,
        connections=tuple(connections),
        step_size_s=macro,
        source=path,
        start_time_s=_number(root, "StartTime", path),
        warnings=tuple(warnings),
    )


def _refuse_ecco(root: ET.Element, path: Path) -> None:
    """ECCO (adaptive step from power bonds) is not built here: refused by name, not run as Jacobi."""
    algorithm = root.find("{*}Algorithm")
    name = (algorithm.text or "").strip() if algorithm is not None else "fixedStep"
    if name.lower() != "fixedstep":
        raise ConfigError(
            f"Algorithm {name!r} is not supported: only fixedStep (libcosim's fixed-step algorithm) is "
            f"built here; ECCO's adaptive step is not; use <Algorithm>fixedStep</Algorithm> [{path}]"
        )
    for element in root.iter():
        bonds = [k for k in (_local(element.tag), *element.attrib) if "powerbond" in k.lower()]
        if bonds:
            raise ConfigError(
                f"power bonds ({bonds[0]} in {_local(element.tag)}) are not supported: they serve ECCO's "
                f"adaptive step, which is not built here; connect the variables with plain "
                f"VariableConnection elements [{path}]"
            )


def decimate(
    components: dict[str, Component], base_s: float | None, path: Path
) -> tuple[dict[str, Component], float | None, list[str]]:
    """The components with their steps as whole numbers of base steps, the macro step (the largest
    step) and a warning for each step rounded (module docstring)."""
    if base_s is None or not any(c.step_size_s for c in components.values()):
        return components, base_s, []
    warnings, factor = [], {}
    for name, c in components.items():
        given = c.step_size_s or base_s
        factor[name] = d = max(1, math.floor(given / base_s * (1 + 1e-9)))
        if not math.isclose(d * base_s, given, rel_tol=1e-9):
            warnings.append(
                f"simulator {name!r}: stepSize {given:g} s is not a whole number of BaseStepSize "
                f"{base_s:g} s; it steps every {d} base steps ({d * base_s:g} s), as libcosim does [{path}]"
            )
    largest = max(factor, key=lambda n: factor[n])
    for name, d in factor.items():
        if factor[largest] % d:
            raise ConfigError(
                f"simulators {name!r} (every {d} base steps, {d * base_s:g} s) and {largest!r} (every "
                f"{factor[largest]} base steps, {factor[largest] * base_s:g} s): the macro step is the "
                f"largest step and {name!r}'s does not divide it; give stepSizes that divide the "
                f"largest one [{path}]"
            )
    stepped = {n: dataclasses.replace(c, step_size_s=factor[n] * base_s) for n, c in components.items()}
    return stepped, factor[largest] * base_s, warnings


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _all(root: ET.Element, container: str, tag: str) -> list[ET.Element]:
    box = root.find(f"{{*}}{container}")
    return [e for e in box if _local(e.tag) == tag] if box is not None else []


def _number(root: ET.Element, tag: str, path: Path) -> float | None:
    element = root.find(f"{{*}}{tag}")
    if element is None or not (element.text or "").strip():
        return None
    try:
        return float(element.text or "")
    except ValueError:
        raise ConfigError(f"{tag}: {element.text!r} is not a number [{path}]") from None


def _simulator(element: ET.Element, path: Path) -> Component:
    name, source = element.attrib.get("name", ""), element.attrib.get("source", "")
    if "://" in source and not source.startswith("file://"):
        raise ConfigError(
            f"simulator {name!r}: source {source!r} is not a file (remote and proxy FMUs are not "
            f"supported); give the FMU's path relative to {path.name} [{path}]"
        )
    fmu = path.parent / source.removeprefix("file://")
    if not source or not fmu.exists():
        raise ConfigError(f"simulator {name!r}: its FMU {source!r} is missing next to {path.name} [{path}]")
    step = element.attrib.get("stepSize")
    return Component(
        name=name,
        fmu=fmu,
        parameters=_initial_values(element, name, path),
        step_size_s=float(step) if step else None,
    )


def _initial_values(element: ET.Element, simulator: str, path: Path) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for initial in _all(element, "InitialValues", "InitialValue"):
        variable = initial.attrib.get("variable", "")
        typed = next(iter(initial), None)
        kind = _local(typed.tag) if typed is not None else ""
        if typed is None or "value" not in typed.attrib or kind not in (*_VALUES, "Boolean"):
            raise ConfigError(
                f"simulator {simulator!r}: InitialValue {variable!r} needs one Real, Integer, "
                f"Boolean, String or Enumeration element with a value [{path}]"
            )
        text = typed.attrib["value"]
        values[variable] = text.strip().lower() in ("true", "1") if kind == "Boolean" else _VALUES[kind](text)
    return values


def _ends(element: ET.Element, tag: str) -> list[tuple[str, str]]:
    return [
        (e.attrib.get("simulator") or e.attrib.get("function") or "", e.attrib.get("name", ""))
        for e in element
        if _local(e.tag) == tag
    ]


def _variable_connection(element: ET.Element, components: dict[str, Component], path: Path) -> Connection:
    ends = _ends(element, "Variable")
    if len(ends) != 2:
        raise ConfigError(f"a VariableConnection needs two Variable elements, got {len(ends)} [{path}]")
    (sa, va), (sb, vb) = ends
    a, b = Endpoint(sa, va), Endpoint(sb, vb)
    return Connection(a, b) if _is_source(a, components, path) else Connection(b, a)


def _is_source(end: Endpoint, components: dict[str, Component], path: Path) -> bool:
    """libcosim's rule: the end that is an output or calculated parameter is the source."""
    from bridge.fmu import read_model_info

    component = components.get(end.component)
    if component is None:
        raise ConfigError(
            f"connection end {end}: {end.component!r} is not a simulator; simulators: "
            f"{list(components)} [{path}]"
        )
    var = read_model_info(component.fmu).variables.get(end.variable)
    return var is not None and var.causality in ("output", "calculatedParameter")


def _functions(root: ET.Element, components: dict[str, Component], path: Path) -> list[Connection]:
    box = root.find("{*}Functions")
    signals = _all(root, "Connections", "SignalConnection")
    declared = {f.attrib.get("name") for f in (box if box is not None else [])}
    for connection in signals:
        (fn, _), *_ = _ends(connection, "Signal") or [("", "")]
        if fn not in declared:
            raise ConfigError(f"SignalConnection: function {fn!r} is not declared in Functions [{path}]")
    found: list[Connection] = []
    for function in box if box is not None else []:
        kind, name = _local(function.tag), function.attrib.get("name", "?")
        if kind != "LinearTransformation":
            raise ConfigError(
                f"function {name!r}: {kind} functions are not supported (only LinearTransformation, "
                f"which becomes a transformation of the connection through it) [{path}]"
            )
        ins, outs = _wired(signals, name, "in"), _wired(signals, name, "out")
        if len(ins) != 1 or not outs:
            raise ConfigError(
                f"function {name!r}: a LinearTransformation needs one SignalConnection into 'in' and "
                f"at least one out of 'out'; found {len(ins)} and {len(outs)} [{path}]"
            )
        transform = Transform(
            "LinearTransformation",
            factor=float(function.attrib.get("factor", "1")),
            offset=float(function.attrib.get("offset", "0")),
        )
        found += [Connection(ins[0], target, transform) for target in outs]
    return found


def _wired(signals: list[ET.Element], function: str, signal: str) -> list[Endpoint]:
    ends = []
    for connection in signals:
        (fn, sig), *_ = _ends(connection, "Signal") or [("", "")]
        variables = _ends(connection, "Variable")
        if fn == function and sig == signal and variables:
            ends.append(Endpoint(*variables[0]))
    return ends
