"""Finding the model sources and reading ``model.json`` into a checked :class:`~bridge.models.spec.Spec`.

The sources are ``models/`` of a source checkout, or ``bridge/_models`` of an installed wheel
(pyproject.toml force-includes the top-level ``models/`` there).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from bridge.errors import BridgeError
from bridge.models.spec import (
    ALL_TYPES,
    CAUSALITIES,
    FLOAT_TYPES,
    FMI2_TYPES,
    FMI_VERSIONS,
    INTERFACES,
    TIME,
    VARIABILITIES,
    VARIABLE_KEYS,
    EnumType,
    Spec,
    Variable,
)

_C_IDENTIFIER: Final = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: C99 keywords and the macros of <stdbool.h> a struct field must not be named after.
_C_KEYWORD_TEXT: Final = """
    auto break case char const continue default do double else enum extern float for goto if inline int long
    register restrict return short signed sizeof static struct switch typedef union unsigned void volatile
    while _Bool _Complex _Imaginary bool true false
"""
_C_KEYWORDS: Final = frozenset(_C_KEYWORD_TEXT.split())
_SPEC_KEYS: Final = frozenset(
    {"description", "variants", "default_experiment", "max_communication_step", "event_indicators"}
    | {"type_definitions", "variables", "once_per_process", "can_serialize", "state_after_initialization"}
    | {"derivatives_in_cs", "equations"}
)


def models_root() -> Path:
    """models/ of a source checkout, or bridge/_models of an installed wheel."""
    bridge_dir = Path(__file__).resolve().parent.parent  # this file is bridge/models/sources.py
    candidates = (bridge_dir / "_models", bridge_dir.parent / "models")
    for candidate in candidates:
        if (candidate / "common" / "fmu_core.h").is_file():
            return candidate
    raise BridgeError(
        "the example model sources were not found: expected common/fmu_core.h under bridge/_models (wheel) "
        "or models/ (source checkout); reinstall fmu-bridge or run from a checkout; looked in: "
        + ", ".join(str(c) for c in candidates)
    )


def model_names() -> list[str]:
    """Names of the example models (directories of ``models/`` with a ``model.json``)."""
    root = models_root()
    return sorted(p.name for p in root.iterdir() if (p / "model.json").is_file())


def load_spec(name: str) -> Spec:
    """Read and check ``models/<name>/model.json``; any problem is a :class:`BridgeError` naming the file."""
    directory = models_root() / name
    path = directory / "model.json"
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise BridgeError(f"cannot read the model specification: {exc}; {path}") from exc
    try:
        return _parse_spec(name, directory, raw)
    except (KeyError, TypeError, ValueError, StopIteration) as exc:
        raise BridgeError(f"invalid model specification ({type(exc).__name__}: {exc}); fix {path}") from exc


def units() -> dict[str, dict[str, int]]:
    """The unit table of ``common/units.json``: unit name -> SI base-unit exponents."""
    raw = json.loads((models_root() / "common" / "units.json").read_text(encoding="utf-8"))
    return {name: dict(exponents) for name, exponents in raw.items() if not name.startswith("_")}


def _parse_spec(name: str, directory: Path, raw: dict[str, Any]) -> Spec:
    _reject_unknown(raw, _SPEC_KEYS, "model")
    variants = tuple((version, iface) for version, ifaces in raw["variants"].items() for iface in ifaces)
    for version, interface in variants:
        if version not in FMI_VERSIONS or interface not in INTERFACES:
            raise ValueError(f"variant {version!r}/{interface!r}: expected {FMI_VERSIONS} and {INTERFACES}")
    max_step = raw.get("max_communication_step")
    spec = Spec(
        name=name,
        directory=directory,
        description=str(raw["description"]),
        variants=variants,
        default_experiment={str(k): float(v) for k, v in raw["default_experiment"].items()},
        max_step_s=None if max_step is None else float(max_step),
        event_indicators=tuple(str(n) for n in raw.get("event_indicators", [])),
        enums={k: _parse_enum(k, v) for k, v in raw.get("type_definitions", {}).items()},
        variables=(TIME, *(_parse_variable(vr, item) for vr, item in enumerate(raw["variables"], start=1))),
        once_per_process=bool(raw.get("once_per_process", False)),
        can_serialize=bool(raw.get("can_serialize", False)),
        state_after_init=bool(raw.get("state_after_initialization", False)),
        cs_derivatives=bool(raw.get("derivatives_in_cs", False)),
        equations=_equations(name, directory, raw.get("equations")),
    )
    _check_spec(spec)
    return spec


def _equations(name: str, directory: Path, equations: Any) -> str | None:
    """``equations``: the model whose ``model.c`` this one compiles instead of having its own."""
    if equations is None:
        return None
    if not isinstance(equations, str) or not (directory.parent / str(equations) / "model.c").is_file():
        raise ValueError(f"equations {equations!r}: expected the name of another model with a model.c")
    if (directory / "model.c").is_file():
        raise ValueError(f"model {name!r} has its own model.c and equations {equations!r}; keep one")
    return equations


def _reject_unknown(raw: Mapping[str, Any], allowed: frozenset[str], where: str) -> None:
    unknown = sorted(set(raw) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}; allowed: {sorted(allowed)}")


def _parse_variable(vr: int, raw: dict[str, Any]) -> Variable:
    """A model.json variable with the FMI defaults filled in; value references count from 1 in file order."""
    _reject_unknown(raw, VARIABLE_KEYS, f"variable {raw.get('name')!r}")
    values = dict(raw)
    values.setdefault("type", "Float64")
    values.setdefault("causality", "local")
    values.setdefault("variability", _default_variability(values["causality"], values["type"]))
    values.setdefault("initial", _default_initial(values["causality"], values["variability"]))
    for key in ("min", "max", "nominal"):
        if key in values:
            values[key] = float(values[key])
    for key in ("fmi_versions", "interfaces", "dimensions"):
        if key in values:
            values[key] = tuple(values[key])
    if isinstance(values.get("start"), list):
        values["start"] = tuple(float(x) for x in values["start"])
    if "interval" in values:
        values["interval"] = float(values["interval"])
    return Variable(vr=vr, **values)


def _default_variability(causality: str, type_: str) -> str:
    if causality in ("parameter", "calculatedParameter"):
        return "fixed"
    return "continuous" if type_ in FLOAT_TYPES else "discrete"


def _default_initial(causality: str, variability: str) -> str | None:
    if causality in ("input", "independent"):
        return None
    if causality == "parameter" or variability == "constant":
        return "exact"
    return "calculated"


def _parse_enum(name: str, raw: dict[str, Any]) -> EnumType:
    items = tuple((str(i["name"]), int(i["value"]), str(i.get("description", ""))) for i in raw["items"])
    return EnumType(name, str(raw.get("description", "")), items)


def _check_spec(spec: Spec) -> None:
    names = [v.name for v in spec.variables]
    if len(set(names)) != len(names):
        raise ValueError(f"variable names are not unique: {names}")
    _check_c_names(spec.variables)
    if spec.can_serialize and any(v.type in ("String", "Binary") for v in spec.variables):
        raise ValueError("can_serialize: the state is saved as bytes; String and Binary are pointers")
    table = units()
    for v in spec.variables:
        _check_variable(spec, v, table)
    for name in spec.event_indicators:
        if spec.variable(name).type != "Float64":
            raise ValueError(f"event indicator {name} must be a Float64 variable")


def _check_c_names(variables: tuple[Variable, ...]) -> None:
    """Every variable needs its own valid C identifier; the name itself becomes a C string literal."""
    seen: dict[str, str] = {}
    for v in variables:
        if not v.name or any(not 32 <= ord(ch) < 127 for ch in v.name):
            raise ValueError(f"{v.name!r}: variable names must be non-empty printable ASCII")
        if not _C_IDENTIFIER.fullmatch(v.c_name) or v.c_name in _C_KEYWORDS:
            raise ValueError(
                f"{v.name}: its C identifier {v.c_name!r} is not a valid C identifier (or is a C keyword); "
                'give one with the key "c", e.g. "c": "x1"'
            )
        if v.c_name in seen:
            raise ValueError(
                f"{v.name}: its C identifier {v.c_name!r} is also the one of {seen[v.c_name]}; "
                'give one of them another with the key "c"'
            )
        seen[v.c_name] = v.name


def _check_variable(spec: Spec, v: Variable, table: Mapping[str, object]) -> None:
    if v.type not in ALL_TYPES or v.causality not in CAUSALITIES or v.variability not in VARIABILITIES:
        raise ValueError(
            f"{v.name}: type/causality/variability {v.type}/{v.causality}/{v.variability} unknown"
        )
    if (v.type == "Enumeration") != (v.declared_type in spec.enums):
        raise ValueError(f"{v.name}: Enumeration variables need a declared_type from type_definitions")
    if v.derivative is not None and spec.variable(v.derivative).type != "Float64":
        raise ValueError(f"{v.name}: the derivative of {v.derivative} must belong to a Float64 state")
    if v.unit is not None and v.unit not in table:
        raise ValueError(f"{v.name}: unit {v.unit!r} is not defined in common/units.json")
    built = {version for version, _ in spec.variants}
    for version in v.fmi_versions:
        if version in built and version != "3.0" and (v.type not in FMI2_TYPES or v.dimensions):
            what = "arrays do" if v.dimensions else f"type {v.type} does"
            raise ValueError(f"{v.name}: {what} not exist in FMI {version}; restrict fmi_versions")
    _check_fmi3_only(v)


def _check_fmi3_only(v: Variable) -> None:
    """Arrays, Binary and Clock: what the generator and the C framework support of them."""
    if v.dimensions:
        if v.type != "Float64" or any(n < 1 for n in v.dimensions):
            raise ValueError(f"{v.name}: arrays must be Float64 with sizes >= 1, got {v.type} {v.dimensions}")
        if isinstance(v.start, tuple) and len(v.start) != v.size:
            raise ValueError(f"{v.name}: start has {len(v.start)} values for {v.size} elements")
    elif isinstance(v.start, tuple):
        raise ValueError(f"{v.name}: a list as start value needs dimensions")
    if v.type == "Binary" and v.start is not None:
        bytes.fromhex(str(v.start))  # ValueError names the bad character
    if (v.type == "Clock") != (v.interval is not None) or (v.interval is not None and v.interval <= 0):
        raise ValueError(
            f"{v.name}: a Clock needs interval > 0 (a constant interval in s); only clocks have one"
        )
