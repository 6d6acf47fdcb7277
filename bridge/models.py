"""Example FMUs of fmu-bridge: our own C models, built into standard ``.fmu`` archives on demand.

Each model lives in ``models/<name>/`` as ``model.json`` (every variable defined once) and ``model.c``
(the equations), over a shared C framework in ``models/common/``. For a variant (FMI version and
interface) this module generates ``modelDescription.xml`` and a C header/table of value references
from ``model.json``, so the XML and the C code cannot drift, compiles everything with gcc against the
FMI headers that FMPy ships, and zips the result. Archives are cached per user, keyed by a hash of
the sources and of this generator, and written atomically so that parallel processes never see a
half-written file.

Example:
    >>> from bridge.models import example_fmu
    >>> path = example_fmu("cartpole", "3.0", "cs")  # builds once, then returns the cached archive
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Final

from bridge.errors import BridgeError, ConfigError, DependencyMissing

__all__ = [
    "CFLAGS",
    "FMI_VERSIONS",
    "INTERFACES",
    "ModelVariant",
    "build_all",
    "cache_dir",
    "example_fmu",
    "list_variants",
    "model_names",
]

logger = logging.getLogger(__name__)

FMI_VERSIONS: Final = ("1.0", "2.0", "3.0")
INTERFACES: Final = ("cs", "me")
#: gcc flags; -fvisibility=hidden keeps everything but the FMI functions out of the symbol table.
CFLAGS: Final = ("-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-fvisibility=hidden")
GENERATION_TOOL: Final = "fmu-bridge (bridge.models)"

_WRAPPERS: Final = {"1.0": "fmi1_cs.c", "2.0": "fmi2.c", "3.0": "fmi3.c"}
_CORE_SOURCES: Final = ("fmu_core.c", "fmu_vars.c", "fmu_solver.c")
_FMI_HEADERS: Final = {
    "1.0": ("fmi1Functions.h",),
    "2.0": ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    "3.0": ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}
_FLOAT_TYPES: Final = frozenset({"Float32", "Float64"})
_UNSIGNED_TYPES: Final = frozenset({"UInt8", "UInt16", "UInt32", "UInt64"})
_INT_TYPES: Final = frozenset({"Int8", "Int16", "Int32", "Int64"}) | _UNSIGNED_TYPES
_ALL_TYPES: Final = _FLOAT_TYPES | _INT_TYPES | {"Boolean", "String", "Enumeration"}
#: FMI 1.0/2.0 element names of the types that exist there (model.json uses the FMI 3.0 names).
_FMI2_TYPES: Final = dict(
    Float64="Real", Int32="Integer", Boolean="Boolean", String="String", Enumeration="Enumeration"
)
_C_TYPES: Final = dict(
    Float32="float", Float64="double", Boolean="bool", String="char*", Enumeration="int64_t"
) | {t: f"{t.lower()}_t" for t in _INT_TYPES}
_CAUSALITIES: Final = ("parameter", "calculatedParameter", "input", "output", "local", "independent")
_VARIABILITIES: Final = ("constant", "fixed", "tunable", "discrete", "continuous")
_LOG_CATEGORIES: Final = {
    "logEvents": "State events, termination requests",
    "logStatusWarning": "Values outside their declared min/max (used unchanged)",
    "logStatusError": "Rejected calls and arguments (always reported)",
}
_SPEC_KEYS: Final = frozenset(
    {"description", "variants", "default_experiment", "max_communication_step", "event_indicators"}
    | {"type_definitions", "variables"}
)

Scalar = float | int | bool | str


@dataclass(frozen=True)
class ModelVariant:
    """One buildable example FMU.

    Attributes:
        name: model name, the directory under ``models/`` and the FMI modelIdentifier.
        fmi_version: ``"1.0"``, ``"2.0"`` or ``"3.0"``.
        interface: ``"cs"`` (co-simulation) or ``"me"`` (model exchange).
        description: what the model is, from its ``model.json``.
    """

    name: str
    fmi_version: str
    interface: str
    description: str

    @property
    def label(self) -> str:
        """Human-readable name, e.g. ``cartpole FMI 2.0 CS``."""
        return f"{self.name} FMI {self.fmi_version} {self.interface.upper()}"


@dataclass(frozen=True)
class _Variable:
    vr: int
    name: str
    type: str
    causality: str
    variability: str
    initial: str | None
    description: str
    start: Scalar | None = None
    unit: str | None = None
    min: float | None = None
    max: float | None = None
    nominal: float | None = None
    declared_type: str | None = None
    derivative: str | None = None
    fmi_versions: tuple[str, ...] = FMI_VERSIONS
    interfaces: tuple[str, ...] = INTERFACES

    @property
    def c_name(self) -> str:
        return "der_" + self.name[4:-1] if self.name.startswith("der(") else self.name

    def present_in(self, fmi_version: str, interface: str) -> bool:
        """Whether the variable appears in this variant's modelDescription.xml (the C struct has all)."""
        in_interface = interface in self.interfaces and (self.derivative is None or interface == "me")
        return fmi_version in self.fmi_versions and in_interface


_VARIABLE_KEYS: Final = frozenset(f.name for f in fields(_Variable)) - {"vr"}


@dataclass(frozen=True)
class _EnumType:
    name: str
    description: str
    items: tuple[tuple[str, int, str], ...]  # (name, value, description)


@dataclass(frozen=True)
class _Spec:
    name: str
    directory: Path
    description: str
    variants: tuple[tuple[str, str], ...]
    default_experiment: Mapping[str, float]
    max_step_s: float | None
    event_indicators: tuple[str, ...]
    enums: Mapping[str, _EnumType]
    variables: tuple[_Variable, ...]

    def variable(self, name: str) -> _Variable:
        return next(v for v in self.variables if v.name == name)

    def states(self) -> list[tuple[_Variable, _Variable]]:
        """(state, derivative) pairs in derivative declaration order."""
        return [(self.variable(d.derivative), d) for d in self.variables if d.derivative is not None]

    def variant_variables(self, fmi_version: str, interface: str) -> list[_Variable]:
        return [v for v in self.variables if v.present_in(fmi_version, interface)]


# --- public API ------------------------------------------------------------------------------------


def model_names() -> list[str]:
    """Names of the example models (directories of ``models/`` with a ``model.json``)."""
    root = _models_root()
    return sorted(p.name for p in root.iterdir() if (p / "model.json").is_file())


def list_variants() -> list[ModelVariant]:
    """Every buildable (model, FMI version, interface) combination, sorted by model name."""
    variants = []
    for name in model_names():
        spec = _load_spec(name)
        variants += [
            ModelVariant(name, version, interface, spec.description) for version, interface in spec.variants
        ]
    return variants


def cache_dir() -> Path:
    """Where built archives are kept: ``$FMU_BRIDGE_CACHE/models``, else ``~/.cache/fmu-bridge/models``.

    ``FMU_BRIDGE_CACHE`` names the fmu-bridge cache root (shared with other cached downloads); the
    directory may be deleted at any time.
    """
    root = os.environ.get("FMU_BRIDGE_CACHE")
    if root:
        return Path(root).expanduser() / "models"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "fmu-bridge" / "models"


def example_fmu(name: str, fmi_version: str = "2.0", interface: str = "cs", *, rebuild: bool = False) -> Path:
    """Path of the example FMU ``name`` for an FMI version and interface, building it if needed.

    Args:
        name: model name, one of :func:`model_names`.
        fmi_version: ``"1.0"``, ``"2.0"`` or ``"3.0"``.
        interface: ``"cs"`` (co-simulation) or ``"me"`` (model exchange).
        rebuild: compile again even if a cached archive with the same source hash exists.

    Raises:
        ConfigError: the model or the variant does not exist (the message lists what does).
        DependencyMissing: gcc or FMPy (for the FMI headers) is not installed.
        BridgeError: gcc failed; the message carries its output.
    """
    spec = _load_spec(_check_name(name))
    _check_variant(spec, fmi_version, interface)
    key = _cache_key(spec, fmi_version, interface)
    target = cache_dir() / f"{name}-fmi{fmi_version[0]}-{interface}-{key[:16]}.fmu"
    if target.is_file() and not rebuild:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    _build(spec, fmi_version, interface, key, target)
    logger.info("built %s", target)
    return target


def build_all(*, rebuild: bool = False) -> list[Path]:
    """Build (or find in the cache) every variant of every example model; gcc runs in parallel.

    Returns:
        The archive paths in the order of :func:`list_variants`.
    """
    variants = list_variants()
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        futures = [
            pool.submit(example_fmu, v.name, v.fmi_version, v.interface, rebuild=rebuild) for v in variants
        ]
        return [future.result() for future in futures]


# --- sources and specs ----------------------------------------------------------------------------


def _models_root() -> Path:
    """models/ of a source checkout, or bridge/_models of an installed wheel."""
    here = Path(__file__).resolve().parent
    candidates = (here / "_models", here.parent / "models")
    for candidate in candidates:
        if (candidate / "common" / "fmu_core.h").is_file():
            return candidate
    raise BridgeError(
        "the example model sources were not found: expected common/fmu_core.h under bridge/_models (wheel) "
        "or models/ (source checkout); reinstall fmu-bridge or run from a checkout; looked in: "
        + ", ".join(str(c) for c in candidates)
    )


def _check_name(name: str) -> str:
    names = model_names()
    if name not in names:
        raise ConfigError(f"model {name!r} is not an example model; available: {', '.join(names)}")
    return name


def _check_variant(spec: _Spec, fmi_version: str, interface: str) -> None:
    if (fmi_version, interface) in spec.variants:
        return
    available = ", ".join(f"fmi_version={v!r} interface={i!r}" for v, i in spec.variants)
    raise ConfigError(
        f"{spec.name} has no FMI {fmi_version!r} {interface!r} variant (fmi_version is one of "
        f"{FMI_VERSIONS}, interface one of {INTERFACES}); available for {spec.name}: {available}"
    )


def _load_spec(name: str) -> _Spec:
    directory = _models_root() / name
    path = directory / "model.json"
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise BridgeError(f"cannot read the model specification: {exc}; {path}") from exc
    try:
        return _parse_spec(name, directory, raw)
    except (KeyError, TypeError, ValueError, StopIteration) as exc:
        raise BridgeError(f"invalid model specification ({type(exc).__name__}: {exc}); fix {path}") from exc


_TIME: Final = _Variable(
    vr=0,
    name="time",
    type="Float64",
    causality="independent",
    variability="continuous",
    initial=None,
    description="Simulation time",
    unit="s",
    fmi_versions=("2.0", "3.0"),
)


def _parse_spec(name: str, directory: Path, raw: dict[str, Any]) -> _Spec:
    _reject_unknown(raw, _SPEC_KEYS, "model")
    variants = tuple((version, iface) for version, ifaces in raw["variants"].items() for iface in ifaces)
    for version, interface in variants:
        if version not in FMI_VERSIONS or interface not in INTERFACES:
            raise ValueError(f"variant {version!r}/{interface!r}: expected {FMI_VERSIONS} and {INTERFACES}")
    max_step = raw.get("max_communication_step")
    spec = _Spec(
        name=name,
        directory=directory,
        description=str(raw["description"]),
        variants=variants,
        default_experiment={str(k): float(v) for k, v in raw["default_experiment"].items()},
        max_step_s=None if max_step is None else float(max_step),
        event_indicators=tuple(str(n) for n in raw.get("event_indicators", [])),
        enums={k: _parse_enum(k, v) for k, v in raw.get("type_definitions", {}).items()},
        variables=(_TIME, *(_parse_variable(vr, item) for vr, item in enumerate(raw["variables"], start=1))),
    )
    _check_spec(spec)
    return spec


def _reject_unknown(raw: Mapping[str, Any], allowed: frozenset[str], where: str) -> None:
    unknown = sorted(set(raw) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}; allowed: {sorted(allowed)}")


def _parse_variable(vr: int, raw: dict[str, Any]) -> _Variable:
    """A model.json variable with the FMI defaults filled in; value references count from 1 in file order."""
    _reject_unknown(raw, _VARIABLE_KEYS, f"variable {raw.get('name')!r}")
    values = dict(raw)
    values.setdefault("type", "Float64")
    values.setdefault("causality", "local")
    values.setdefault("variability", _default_variability(values["causality"], values["type"]))
    values.setdefault("initial", _default_initial(values["causality"], values["variability"]))
    for key in ("min", "max", "nominal"):
        if key in values:
            values[key] = float(values[key])
    for key in ("fmi_versions", "interfaces"):
        if key in values:
            values[key] = tuple(values[key])
    return _Variable(vr=vr, **values)


def _default_variability(causality: str, type_: str) -> str:
    if causality in ("parameter", "calculatedParameter"):
        return "fixed"
    return "continuous" if type_ in _FLOAT_TYPES else "discrete"


def _default_initial(causality: str, variability: str) -> str | None:
    if causality in ("input", "independent"):
        return None
    if causality == "parameter" or variability == "constant":
        return "exact"
    return "calculated"


def _parse_enum(name: str, raw: dict[str, Any]) -> _EnumType:
    items = tuple((str(i["name"]), int(i["value"]), str(i.get("description", ""))) for i in raw["items"])
    return _EnumType(name, str(raw.get("description", "")), items)


def _check_spec(spec: _Spec) -> None:
    names = [v.name for v in spec.variables]
    if len(set(names)) != len(names):
        raise ValueError(f"variable names are not unique: {names}")
    units = _units()
    for v in spec.variables:
        _check_variable(spec, v, units)
    for name in spec.event_indicators:
        if spec.variable(name).type != "Float64":
            raise ValueError(f"event indicator {name} must be a Float64 variable")


def _check_variable(spec: _Spec, v: _Variable, units: Mapping[str, object]) -> None:
    if v.type not in _ALL_TYPES or v.causality not in _CAUSALITIES or v.variability not in _VARIABILITIES:
        raise ValueError(
            f"{v.name}: type/causality/variability {v.type}/{v.causality}/{v.variability} unknown"
        )
    if not v.c_name.isidentifier():
        raise ValueError(f"{v.name}: not usable as a C identifier ({v.c_name})")
    if (v.type == "Enumeration") != (v.declared_type in spec.enums):
        raise ValueError(f"{v.name}: Enumeration variables need a declared_type from type_definitions")
    if v.derivative is not None and spec.variable(v.derivative).type != "Float64":
        raise ValueError(f"{v.name}: the derivative of {v.derivative} must belong to a Float64 state")
    if v.unit is not None and v.unit not in units:
        raise ValueError(f"{v.name}: unit {v.unit!r} is not defined in common/units.json")
    for version in v.fmi_versions:
        if version != "3.0" and v.type not in _FMI2_TYPES:
            raise ValueError(
                f"{v.name}: type {v.type} does not exist in FMI {version}; restrict fmi_versions"
            )


def _units() -> dict[str, dict[str, int]]:
    raw = json.loads((_models_root() / "common" / "units.json").read_text(encoding="utf-8"))
    return {name: dict(exponents) for name, exponents in raw.items() if not name.startswith("_")}


# --- generated C ----------------------------------------------------------------------------------


def _c_string(text: str) -> str:
    if any(not (32 <= ord(c) < 127) for c in text):
        raise BridgeError(f"C string literals of the generator must be printable ASCII, got {text!r}")
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_header(spec: _Spec, fmi_version: str, interface: str, token: str) -> str:
    nx, nz = len(spec.states()), len(spec.event_indicators)
    max_step = "HUGE_VAL" if spec.max_step_s is None else repr(spec.max_step_s)
    lines = [
        f"/* Generated by bridge/models.py from models/{spec.name}/model.json for FMI {fmi_version} "
        f"{interface.upper()}. Do not edit. */",
        "#ifndef MODEL_GEN_H",
        "#define MODEL_GEN_H",
        "",
        "#include <math.h>",
        '#include "fmu_types.h"',
        "",
        f"#define MODEL_NAME {_c_string(spec.name)}",
        f"#define MODEL_IDENTIFIER {spec.name}",
        f"#define INSTANTIATION_TOKEN {_c_string(token)}",
        f"#define MODEL_INTERFACE {'FMU_CS' if interface == 'cs' else 'FMU_ME'}",
        f"#define MODEL_FMI_VERSION {fmi_version[0]}",
        f"#define MODEL_MAX_STEP {max_step}",
        f"#define MODEL_NX {nx}",
        f"#define MODEL_NX_ALLOC {max(nx, 1)}",
        f"#define MODEL_NZ {nz}",
        f"#define MODEL_NZ_ALLOC {max(nz, 1)}",
        f"#define MODEL_N_VARS {len(spec.variables)}",
        "",
        "/* value references */",
        *(f"#define VR_{v.c_name} {v.vr}" for v in spec.variables),
        "",
        *(f"#define {e.name}_{item} {value}" for e in spec.enums.values() for item, value, _ in e.items),
        *([""] if spec.enums else []),
        "typedef struct {",
        *(f"    {_C_TYPES[v.type]} {v.c_name};  /* {_c_comment(v)} */" for v in spec.variables[1:]),
        "} ModelData;",
        "",
        "extern const FmuVariable MODEL_VARIABLES[MODEL_N_VARS];",
        "extern const size_t MODEL_STATE_OFFSETS[MODEL_NX_ALLOC];",
        "extern const size_t MODEL_DERIVATIVE_OFFSETS[MODEL_NX_ALLOC];",
        "extern const double MODEL_STATE_NOMINALS[MODEL_NX_ALLOC];",
        "extern const size_t MODEL_EVENT_INDICATOR_OFFSETS[MODEL_NZ_ALLOC];",
        "",
        "#endif /* MODEL_GEN_H */",
    ]
    return "\n".join(lines) + "\n"


def _c_comment(v: _Variable) -> str:
    unit = f"[{v.unit}] " if v.unit else ""
    return f"{v.causality}, {unit}{v.description}".replace("*/", "* /")


def _c_table(spec: _Spec, fmi_version: str, interface: str) -> str:
    def offsets(variables: Iterable[_Variable]) -> str:
        return ", ".join(f"offsetof(ModelData, {v.c_name})" for v in variables) or "0"

    states = spec.states()
    nominals = ", ".join(repr(s.nominal or 1.0) for s, _ in states) or "0.0"
    rows = ",\n".join(
        f"    [VR_{v.c_name}] = {{{_c_row(spec, v, fmi_version, interface)}}}" for v in spec.variables
    )
    return "\n".join(
        [
            f"/* Generated by bridge/models.py from models/{spec.name}/model.json. Do not edit. */",
            "#include <stddef.h>",
            '#include "model_gen.h"',
            "",
            f"const FmuVariable MODEL_VARIABLES[MODEL_N_VARS] = {{\n{rows}\n}};",
            "",
            f"const size_t MODEL_STATE_OFFSETS[MODEL_NX_ALLOC] = {{{offsets(s for s, _ in states)}}};",
            f"const size_t MODEL_DERIVATIVE_OFFSETS[MODEL_NX_ALLOC] = {{{offsets(d for _, d in states)}}};",
            f"const double MODEL_STATE_NOMINALS[MODEL_NX_ALLOC] = {{{nominals}}};",
            "const size_t MODEL_EVENT_INDICATOR_OFFSETS[MODEL_NZ_ALLOC] = "
            f"{{{offsets(spec.variable(n) for n in spec.event_indicators)}}};",
            "",
        ]
    )


def _c_row(spec: _Spec, v: _Variable, fmi_version: str, interface: str) -> str:
    causality = "C_" + "".join("_" + c if c.isupper() else c for c in v.causality).upper()
    offset = "0" if v.causality == "independent" else f"offsetof(ModelData, {v.c_name})"
    fields = [
        f".name = {_c_string(v.name)}",
        f".type = T_{v.type.upper()}",
        f".causality = {causality}",
        f".variability = V_{v.variability.upper()}",
        f".exposed = {str(v.present_in(fmi_version, interface)).lower()}",
        f".offset = {offset}",
    ]
    if v.start is not None:
        fields += [".has_start = true", _c_start(v)]
    low, high = (v.min, v.max)
    if v.type == "Enumeration" and v.declared_type is not None:
        values = [value for _, value, _ in spec.enums[v.declared_type].items]
        low, high = float(min(values)), float(max(values))
    if low is not None:
        fields += [".has_min = true", f".min = {low!r}"]
    if high is not None:
        fields += [".has_max = true", f".max = {high!r}"]
    return ", ".join(fields)


def _c_start(v: _Variable) -> str:
    if v.type == "String":
        return f".start_string = {_c_string(str(v.start))}"
    if v.type in _FLOAT_TYPES:
        return f".start_real = {float(v.start or 0.0)!r}"
    if v.type in _UNSIGNED_TYPES:
        return f".start_uint = UINT64_C({int(v.start or 0)})"
    return f".start_int = INT64_C({int(v.start or 0)})"


# --- modelDescription.xml --------------------------------------------------------------------------


def _xml_value(value: Scalar) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _attributes(**values: Scalar | None) -> dict[str, str]:
    return {key: _xml_value(value) for key, value in values.items() if value is not None}


def _model_description(spec: _Spec, fmi_version: str, interface: str, token: str) -> bytes:
    if fmi_version == "1.0":
        root = _xml_fmi1(spec, interface, token)
    else:
        root = _xml_fmi23(spec, fmi_version, interface, token)
    ET.indent(root)
    text: bytes = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    return text + b"\n"


def _units_element(variables: Iterable[_Variable], fmi1: bool = False) -> ET.Element | None:
    used = sorted({v.unit for v in variables if v.unit is not None})
    if not used:
        return None
    element = ET.Element("UnitDefinitions")
    table = _units()
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


def _default_experiment(spec: _Spec, keys: tuple[str, ...]) -> ET.Element:
    values = {k: _xml_value(float(v)) for k, v in spec.default_experiment.items() if k in keys}
    return ET.Element("DefaultExperiment", values)


def _log_categories() -> ET.Element:
    element = ET.Element("LogCategories")
    for name, description in _LOG_CATEGORIES.items():
        ET.SubElement(element, "Category", name=name, description=description)
    return element


def _root(version: str, spec: _Spec, **attributes: str) -> ET.Element:
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


def _type_attributes(v: _Variable, fmi_version: str) -> dict[str, str]:
    numeric = v.type in _FLOAT_TYPES or v.type in _INT_TYPES
    start = None if (v.type == "String" and fmi_version == "3.0") else v.start  # FMI 3.0: <Start value=.../>
    return _attributes(
        declaredType=v.declared_type,
        unit=v.unit,
        start=start,
        min=v.min if numeric else None,
        max=v.max if numeric else None,
        nominal=v.nominal,
    )


def _type_definitions(spec: _Spec, fmi_version: str) -> ET.Element | None:
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


def _xml_fmi1(spec: _Spec, interface: str, token: str) -> ET.Element:
    """FMI 1.0 co-simulation stand-alone: no ModelStructure, causality internal, variability parameter."""
    variables = spec.variant_variables("1.0", interface)
    counts = {"numberOfContinuousStates": "0", "numberOfEventIndicators": "0"}  # CS exposes neither
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
        ET.SubElement(scalar, _FMI2_TYPES[v.type], _type_attributes(v, "1.0"))
    standalone = ET.SubElement(ET.SubElement(root, "Implementation"), "CoSimulation_StandAlone")
    flags = ("canHandleVariableCommunicationStepSize", "canNotUseMemoryManagementFunctions")
    ET.SubElement(standalone, "Capabilities", dict.fromkeys(flags, "true"))
    return root


def _interface_element(spec: _Spec, fmi_version: str, interface: str) -> ET.Element:
    flags = {"modelIdentifier": spec.name}
    if fmi_version == "2.0":
        flags |= {"canGetAndSetFMUstate": "true", "canNotUseMemoryManagementFunctions": "true"}
    else:
        flags |= {"canGetAndSetFMUState": "true"}
    if interface == "cs":
        return ET.Element("CoSimulation", flags | {"canHandleVariableCommunicationStepSize": "true"})
    if fmi_version == "2.0":
        flags |= {"completedIntegratorStepNotNeeded": "true"}
    return ET.Element("ModelExchange", flags)


def _variable_element(v: _Variable, fmi_version: str) -> tuple[ET.Element, ET.Element]:
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
        return scalar, ET.SubElement(scalar, _FMI2_TYPES[v.type], _type_attributes(v, "2.0"))
    element = ET.Element(v.type, common | _type_attributes(v, "3.0"))
    if v.type == "String" and v.start is not None:
        ET.SubElement(element, "Start", value=str(v.start))
    return element, element


def _initial_unknowns(spec: _Spec, variables: list[_Variable], interface: str) -> list[_Variable]:
    """Outputs and states/derivatives whose initial value the FMU computes, and calculated parameters."""
    computed = ("approx", "calculated")
    unknowns = {
        v.vr: v
        for v in variables
        if v.causality == "calculatedParameter" or (v.causality == "output" and v.initial in computed)
    }
    if interface == "me":
        for state, derivative in spec.states():
            unknowns |= {v.vr: v for v in (state, derivative) if v.initial in computed}
    return [unknowns[vr] for vr in sorted(unknowns)]


def _model_structure(spec: _Spec, variables: list[_Variable], fmi_version: str, interface: str) -> ET.Element:
    me = interface == "me"
    groups = {  # (FMI 2.0 list element, FMI 3.0 element): members
        ("Outputs", "Output"): [v for v in variables if v.causality == "output"],
        ("Derivatives", "ContinuousStateDerivative"): [d for _, d in spec.states()] if me else [],
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


def _xml_fmi23(spec: _Spec, fmi_version: str, interface: str, token: str) -> ET.Element:
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


# --- build and cache ------------------------------------------------------------------------------


def _fmi_headers_dir() -> Path:
    """FMPy's copy of the FMI headers, found without importing FMPy (only bridge.fmu imports it)."""
    found = importlib.util.find_spec("fmpy")
    if found is None or found.origin is None:
        raise DependencyMissing("fmpy", "the FMI headers used to build the example FMUs", "pip install fmpy")
    directory = Path(found.origin).parent / "c-code"
    if not (directory / "fmi3Functions.h").is_file():
        raise BridgeError(
            f"FMPy's FMI headers are missing; expected fmi3Functions.h; reinstall fmpy: {directory}"
        )
    return directory


def _find_gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise DependencyMissing("gcc", "building the example FMUs", "sudo apt-get install gcc")
    return gcc


def _source_files(spec: _Spec) -> list[Path]:
    common = spec.directory.parent / "common"
    return sorted(p for d in (common, spec.directory) for p in d.iterdir() if p.is_file())


def _cache_key(spec: _Spec, fmi_version: str, interface: str) -> str:
    """sha256 over the model's and the framework's sources, the FMI headers, this generator and the flags."""
    digest = hashlib.sha256()
    headers = _fmi_headers_dir()
    files = [*_source_files(spec), Path(__file__), *(headers / h for h in _FMI_HEADERS[fmi_version])]
    for path in files:
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update(" ".join((spec.name, fmi_version, interface, *CFLAGS)).encode())
    return digest.hexdigest()


def _binary_path(name: str, fmi_version: str) -> str:
    """binaries/<platform>/<id>.<ext>: FMI 1.0/2.0 names (linux64) or FMI 3.0 tuples (x86_64-linux)."""
    system = {"linux": "linux", "darwin": "darwin", "win32": "windows"}.get(sys.platform, sys.platform)
    extension = {"linux": ".so", "darwin": ".dylib", "windows": ".dll"}.get(system, ".so")
    machine = platform.machine().lower()
    arch = "aarch64" if machine in ("aarch64", "arm64") else ("x86_64" if sys.maxsize > 2**32 else "x86")
    if fmi_version == "3.0":
        directory = f"{arch}-{system}"
    else:
        bits = "64" if arch in ("x86_64", "aarch64") else "32"
        directory = ("win" if system == "windows" else system) + bits
    return f"binaries/{directory}/{name}{extension}"


def _build(spec: _Spec, fmi_version: str, interface: str, key: str, target: Path) -> None:
    gcc, headers = _find_gcc(), _fmi_headers_dir()
    common = spec.directory.parent / "common"
    token = "{" + str(uuid.UUID(hex=key[:32])) + "}"
    with tempfile.TemporaryDirectory(prefix=f".build-{spec.name}-", dir=target.parent) as tmp:
        work = Path(tmp)
        (work / "model_gen.h").write_text(_c_header(spec, fmi_version, interface, token), encoding="ascii")
        (work / "model_gen.c").write_text(_c_table(spec, fmi_version, interface), encoding="ascii")
        sources = [
            *(common / s for s in _CORE_SOURCES),
            common / _WRAPPERS[fmi_version],
            spec.directory / "model.c",
            work / "model_gen.c",
        ]
        library = work / "library"
        command = [
            gcc,
            *CFLAGS,
            f"-I{work}",
            f"-I{common}",
            f"-I{headers}",
            "-o",
            str(library),
            *(str(s) for s in sources),
            "-lm",
        ]
        _compile(command, f"{spec.name} FMI {fmi_version} {interface.upper()}")
        files = {
            "modelDescription.xml": _model_description(spec, fmi_version, interface, token),
            _binary_path(spec.name, fmi_version): library.read_bytes(),
            "sources/model_gen.h": (work / "model_gen.h").read_bytes(),
            "sources/model_gen.c": (work / "model_gen.c").read_bytes(),
        }
        for path in (
            *sources[:-1],
            common / "fmu_core.h",
            common / "fmu_types.h",
            spec.directory / "model.json",
        ):
            files[f"sources/{path.name}"] = path.read_bytes()
        partial = work / "archive.fmu"
        _write_zip(partial, files)
        os.replace(partial, target)  # atomic: readers see the old archive or the complete new one


def _compile(command: list[str], label: str) -> None:
    logger.debug("compiling %s: %s", label, " ".join(command))
    try:
        result = subprocess.run(command, capture_output=True, text=True, check=False)
    except FileNotFoundError as exc:
        raise DependencyMissing("gcc", "building the example FMUs", "sudo apt-get install gcc") from exc
    if result.returncode != 0:
        raise BridgeError(
            f"gcc failed to build {label} (exit code {result.returncode}); fix the C sources. gcc said:\n"
            f"{result.stderr.strip()}\ncommand: {' '.join(command)}"
        )
    if result.stderr.strip():
        logger.warning("gcc warnings while building %s:\n%s", label, result.stderr.strip())


def _write_zip(path: Path, files: Mapping[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, files[name])
