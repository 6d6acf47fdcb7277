"""``modelDescription.xml`` of an example FMU for FMI 1.0 (co-simulation stand-alone), 2.0 or 3.0.

Written from the same :class:`~bridge.models.spec.Spec` as the generated C, with ElementTree;
model.json uses the FMI 3.0 type names, which FMI 1.0/2.0 map to their element names.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from typing import Final

from bridge.errors import BridgeError
from bridge.models.sources import units
from bridge.models.spec import FLOAT_TYPES, FMI2_TYPES, INT_TYPES, Spec, Start, Variable

GENERATION_TOOL: Final = "fmu-bridge (bridge.models)"

_LOG_CATEGORIES: Final = {
    "logEvents": "State events, termination requests",
    "logStatusWarning": "Values outside their declared min/max (used unchanged)",
    "logStatusError": "Rejected calls and arguments (always reported)",
}


def _xml_value(value: Start) -> str:
    if isinstance(value, tuple):  # an array's start: one value per element, space separated
        return " ".join(_xml_value(x) for x in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _attributes(**values: Start | None) -> dict[str, str]:
    return {key: _xml_value(value) for key, value in values.items() if value is not None}


def model_description(spec: Spec, fmi_version: str, interface: str, token: str) -> bytes:
    """The UTF-8 XML of one variant; ``token`` is the FMI 1.0/2.0 guid or the FMI 3.0 instantiationToken."""
    if fmi_version == "1.0":
        root = _xml_fmi1(spec, interface, token)
    else:
        root = _xml_fmi23(spec, fmi_version, interface, token)
    ET.indent(root)
    text: bytes = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    return text + b"\n"


def _units_element(variables: Iterable[Variable], fmi1: bool = False) -> ET.Element | None:
    used = sorted({v.unit for v in variables if v.unit is not None})
    if not used:
        return None
    element = ET.Element("UnitDefinitions")
    table = units()
    for unit in used:
        if fmi1:
            ET.SubElement(element, "BaseUnit", unit=unit)
        else:
            ET.SubElement(
                ET.SubElement(element, "Unit", name=unit),
                "BaseUnit",
                {k: str(e) for k, e in table[unit].items()},
            )
    return element


def _default_experiment(spec: Spec, keys: tuple[str, ...]) -> ET.Element:
    values = {k: _xml_value(float(v)) for k, v in spec.default_experiment.items() if k in keys}
    return ET.Element("DefaultExperiment", values)


def _log_categories() -> ET.Element:
    element = ET.Element("LogCategories")
    for name, description in _LOG_CATEGORIES.items():
        ET.SubElement(element, "Category", name=name, description=description)
    return element


def _root(version: str, spec: Spec, **attributes: str) -> ET.Element:
    return ET.Element(
        "fmiModelDescription",
        {
            "fmiVersion": version,
            "modelName": spec.name,
            **attributes,
            "description": spec.description,
            "generationTool": GENERATION_TOOL,
            "variableNamingConvention": "structured",
        },
    )


def _append(parent: ET.Element, *children: ET.Element | None) -> None:
    parent.extend(child for child in children if child is not None)


def _type_attributes(v: Variable, fmi_version: str) -> dict[str, str]:
    numeric = v.type in FLOAT_TYPES or v.type in INT_TYPES
    child_start = fmi_version == "3.0" and v.type in ("String", "Binary")  # FMI 3.0: <Start value=.../>
    start = None if child_start else v.start
    if v.dimensions and start is not None and not isinstance(start, tuple):
        start = (float(start),) * v.size
    return _attributes(
        declaredType=v.declared_type,
        unit=v.unit,
        start=start,
        min=_bound(v, v.min) if numeric else None,
        max=_bound(v, v.max) if numeric else None,
        nominal=v.nominal,
    )


def _bound(v: Variable, value: float | None) -> float | int | None:
    """Integer types declare whole-number bounds (xs:int/xs:long in the schemas)."""
    return int(value) if value is not None and v.type in INT_TYPES else value


def _type_definitions(spec: Spec, fmi_version: str) -> ET.Element | None:
    if not spec.enums:
        return None
    if fmi_version == "1.0":
        raise BridgeError(
            f"{spec.name}: Enumeration types are not generated for FMI 1.0; restrict fmi_versions"
        )
    element = ET.Element("TypeDefinitions")
    for enum in spec.enums.values():
        if fmi_version == "2.0":
            simple = ET.SubElement(element, "SimpleType", name=enum.name, description=enum.description)
            container = ET.SubElement(simple, "Enumeration")
        else:
            container = ET.SubElement(
                element, "EnumerationType", name=enum.name, description=enum.description
            )
        for item, value, description in enum.items:
            ET.SubElement(container, "Item", name=item, value=str(value), description=description)
    return element


def _xml_fmi1(spec: Spec, interface: str, token: str) -> ET.Element:
    """FMI 1.0 model exchange or co-simulation stand-alone: causality internal, variability parameter."""
    variables = spec.variant_variables("1.0", interface)
    me = interface == "me"
    counts = {  # CS exposes neither
        "numberOfContinuousStates": str(len(spec.states()) if me else 0),
        "numberOfEventIndicators": str(len(spec.event_indicators) if me else 0),
    }
    root = _root("1.0", spec, modelIdentifier=spec.name, guid=token, **counts)
    experiment = _default_experiment(spec, ("startTime", "stopTime", "tolerance"))
    _append(root, _units_element(variables, fmi1=True), _type_definitions(spec, "1.0"), experiment)
    model_variables = ET.SubElement(root, "ModelVariables")
    for v in variables:
        variability = "parameter" if v.causality in ("parameter", "calculatedParameter") else v.variability
        causality = v.causality if v.causality in ("input", "output") else "internal"
        attributes = _attributes(
            name=v.name,
            valueReference=v.vr,
            description=v.description,
            variability=variability,
            causality=causality,
        )
        scalar = ET.SubElement(model_variables, "ScalarVariable", attributes)
        ET.SubElement(scalar, FMI2_TYPES[v.type], _type_attributes(v, "1.0"))
    if me:
        return root  # an FMI 1.0 model-exchange description has no Implementation element
    standalone = ET.SubElement(ET.SubElement(root, "Implementation"), "CoSimulation_StandAlone")
    flags = ("canHandleVariableCommunicationStepSize", "canNotUseMemoryManagementFunctions")
    ET.SubElement(standalone, "Capabilities", dict.fromkeys(flags, "true"))
    return root


def _interface_element(spec: Spec, fmi_version: str, interface: str) -> ET.Element:
    flags = {"modelIdentifier": spec.name}
    state = "true"
    if spec.once_per_process:  # its state is in globals, which an instance's FMU state does not hold
        flags["canBeInstantiatedOnlyOncePerProcess"] = "true"
        state = "false"
    serialize = str(spec.can_serialize and state == "true").lower()
    if fmi_version == "2.0":
        flags |= {"canGetAndSetFMUstate": state, "canNotUseMemoryManagementFunctions": "true"}
        flags |= {"canSerializeFMUstate": serialize}
    else:
        flags |= {"canGetAndSetFMUState": state, "canSerializeFMUState": serialize}
    if interface == "cs":
        return ET.Element("CoSimulation", flags | {"canHandleVariableCommunicationStepSize": "true"})
    if fmi_version == "2.0":
        flags |= {"completedIntegratorStepNotNeeded": "true"}
    return ET.Element("ModelExchange", flags)


def _variable_element(v: Variable, fmi_version: str) -> tuple[ET.Element, ET.Element]:
    """(element to append to ModelVariables, element that carries the type attributes)."""
    common = _attributes(
        name=v.name,
        valueReference=v.vr,
        description=v.description,
        causality=v.causality,
        variability=v.variability,
        initial=v.initial,
    )
    if fmi_version == "2.0":
        scalar = ET.Element("ScalarVariable", common)
        return scalar, ET.SubElement(scalar, FMI2_TYPES[v.type], _type_attributes(v, "2.0"))
    if v.type == "Clock":  # a time-based clock with a constant interval; no start, no initial
        clock = _attributes(intervalVariability="constant", intervalDecimal=v.interval)
        return ET.Element("Clock", common | clock), ET.Element("Clock")
    element = ET.Element(v.type, common | _type_attributes(v, "3.0"))
    for size in v.dimensions:
        ET.SubElement(element, "Dimension", start=str(size))
    if v.type in ("String", "Binary") and v.start is not None:
        ET.SubElement(element, "Start", value=str(v.start))
    return element, element


def _initial_unknowns(spec: Spec, variables: list[Variable], interface: str) -> list[Variable]:
    """Outputs and states/derivatives whose initial value the FMU computes, and calculated parameters."""
    computed = ("approx", "calculated")
    unknowns = {
        v.vr: v
        for v in variables
        if v.causality == "calculatedParameter" or (v.causality == "output" and v.initial in computed)
    }
    if interface == "me" or spec.cs_derivatives:
        for state, derivative in spec.states():
            unknowns |= {v.vr: v for v in (state, derivative) if v.initial in computed}
    return [unknowns[vr] for vr in sorted(unknowns)]


def _model_structure(spec: Spec, variables: list[Variable], fmi_version: str, interface: str) -> ET.Element:
    me = interface == "me"
    groups = {  # (FMI 2.0 list element, FMI 3.0 element): members
        ("Outputs", "Output"): [v for v in variables if v.causality == "output"],
        ("Derivatives", "ContinuousStateDerivative"): (
            [d for _, d in spec.states()] if me or spec.cs_derivatives else []
        ),
        ("InitialUnknowns", "InitialUnknown"): _initial_unknowns(spec, variables, interface),
        ("", "EventIndicator"): [spec.variable(n) for n in spec.event_indicators] if me else [],
    }
    index = {v.name: position for position, v in enumerate(variables, start=1)}
    structure = ET.Element("ModelStructure")
    for (fmi2_list, fmi3_tag), members in groups.items():
        if fmi_version == "3.0":
            structure.extend(ET.Element(fmi3_tag, valueReference=str(v.vr)) for v in members)
        elif members and fmi2_list:
            container = ET.SubElement(structure, fmi2_list)
            container.extend(ET.Element("Unknown", index=str(index[v.name])) for v in members)
    return structure


def _xml_fmi23(spec: Spec, fmi_version: str, interface: str, token: str) -> ET.Element:
    variables = spec.variant_variables(fmi_version, interface)
    if fmi_version == "2.0":
        extra = {"numberOfEventIndicators": str(len(spec.event_indicators))} if interface == "me" else {}
        root = _root("2.0", spec, guid=token, **extra)
    else:
        root = _root("3.0", spec, instantiationToken=token)
    experiment = _default_experiment(spec, ("startTime", "stopTime", "tolerance", "stepSize"))
    _append(
        root,
        _interface_element(spec, fmi_version, interface),
        _units_element(variables),
        _type_definitions(spec, fmi_version),
        _log_categories(),
        experiment,
    )
    model_variables = ET.SubElement(root, "ModelVariables")
    index = {v.name: position for position, v in enumerate(variables, start=1)}
    for v in variables:
        element, typed = _variable_element(v, fmi_version)
        if v.derivative is not None:  # FMI 2.0: 1-based variable index; FMI 3.0: value reference
            state = spec.variable(v.derivative)
            typed.set("derivative", str(index[state.name] if fmi_version == "2.0" else state.vr))
        model_variables.append(element)
    root.append(_model_structure(spec, variables, fmi_version, interface))
    return root
