"""What an FMU declares: variables, interfaces, default experiment, platforms.

Reading a model description needs no binary, so ``inspect`` works on any FMU,
including ones built for other platforms.
"""

from __future__ import annotations

import io
import logging
import zipfile
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import fmpy
from fmpy.model_description import ModelDescription, ModelVariable, ValidationError, read_model_description

from bridge.errors import FmuLoadError
from bridge.fmu import python_backed, unzip
from bridge.fmu.vocab import (
    NUMERIC_TYPES,
    ClockInfo,
    DefaultExperiment,
    Interface,
    ModelInfo,
    Variable,
    unknown_variable_error,
)

__all__ = [
    "NUMERIC_TYPES",
    "DefaultExperiment",
    "Interface",
    "ModelInfo",
    "Variable",
    "read_model_info",
    "unknown_variable_error",
]

_log = logging.getLogger(__name__)

# FMI 1/2 type names mapped onto the FMI 3 vocabulary; FMI 1/2 Integer is 32 bit.
_TYPE_ALIASES = {"Real": "Float64", "Integer": "Int32"}


def read_model_info(path: str | Path) -> ModelInfo:
    """Read an FMU's model description (parsed once per file version: a batch of N instances, or
    a scenario grid, reads it once; an FMU rewritten in place is read again).

    Raises:
        FmuLoadError: the file is missing, not a zip archive, or has no valid modelDescription.xml.
    """
    try:
        fmu_path = Path(path).expanduser().resolve()
    except (RuntimeError, OSError) as exc:  # a symbolic link loop (RuntimeError up to Python 3.12)
        raise FmuLoadError(f"cannot read FMU: {exc} [{path}]") from None
    try:
        stat = fmu_path.stat()
    except OSError:
        return _model_info(fmu_path, None)  # missing: the uncached read says so
    version = (stat.st_mtime_ns, stat.st_size, stat.st_ino, stat.st_ctime_ns)
    return _model_info(fmu_path, version if fmu_path.is_file() else None)


def _model_info(fmu_path: Path, version: tuple[int, ...] | None) -> ModelInfo:
    if version is None:  # a missing file or an extracted directory: read it every time
        return _parse_model_info(fmu_path)
    return _cached_model_info(fmu_path, version)


@lru_cache(maxsize=64)
def _cached_model_info(fmu_path: Path, version: tuple[int, ...]) -> ModelInfo:
    return _parse_model_info(fmu_path)


def _parse_model_info(fmu_path: Path) -> ModelInfo:
    md, problems = _read_description(fmu_path)
    names = _entry_names(fmu_path)
    interfaces: list[Interface] = []
    identifiers: dict[str, str] = {}
    can_state: dict[str, bool] = {}
    once_per_process = needs_tool = False
    for kind, iface in (("cs", md.coSimulation), ("me", md.modelExchange), ("se", md.scheduledExecution)):
        if iface is not None:
            interfaces.append(kind)  # type: ignore[arg-type]
            identifiers[kind] = iface.modelIdentifier
            can_state[kind] = bool(iface.canGetAndSetFMUstate)
            once_per_process |= bool(iface.canBeInstantiatedOnlyOncePerProcess)
            needs_tool |= bool(iface.needsExecutionTool)
    scheduled = md.scheduledExecution is not None
    if not interfaces and not scheduled:
        raise FmuLoadError(
            f"{fmu_path.name} declares no interface: fmu-bridge runs co-simulation and model "
            f"exchange; re-export it with one of them [{fmu_path}]"
        )
    return ModelInfo(
        path=fmu_path,
        fmi_version=md.fmiVersion,
        model_name=md.modelName,
        guid=md.guid,
        interfaces=tuple(interfaces),
        model_identifiers=identifiers,
        default_experiment=_default_experiment(md),
        platforms=_platforms(fmu_path, names),
        variables=_variables(md, fmu_path),
        can_get_set_state=can_state,
        number_of_states=int(md.numberOfContinuousStates or 0),
        number_of_event_indicators=int(md.numberOfEventIndicators or 0),
        generation_tool=md.generationTool,
        description=md.description,
        problems=problems + _backslash_problem(names),
        scheduled_execution=scheduled,
        has_event_mode=bool(md.coSimulation is not None and md.coSimulation.hasEventMode),
        once_per_process=once_per_process,
        needs_execution_tool=needs_tool,
        python_backed=python_backed.is_python_backed(fmu_path, md.generationTool),
        python_requirements=python_backed.requirements(fmu_path),
        raw=md,
    )


def _platforms(fmu_path: Path, names: list[str]) -> tuple[str, ...]:
    """The platforms the archive has binaries (or sources) for. Archives zipped on Windows may
    name their entries with backslashes (``binaries\\win64\\m.dll``, against the zip format);
    FMPy's reading of the names is given them with forward slashes."""
    if not fmu_path.is_file():
        return ()
    if not any("\\" in name for name in names):
        return tuple(fmpy.supported_platforms(str(fmu_path)))
    listing = io.BytesIO()
    with zipfile.ZipFile(listing, "w") as names_only:
        for name in sorted({name.replace("\\", "/") for name in names}):
            names_only.writestr(name, b"")
    return tuple(fmpy.supported_platforms(listing))


def _backslash_problem(names: list[str]) -> tuple[str, ...]:
    if not any("\\" in name for name in names):
        return ()
    return (
        "the archive names its entries with backslashes (the zip format wants '/'); fmu-bridge "
        "does not extract it: unzip it and zip it again with forward slashes (any zip tool on "
        "Linux or macOS, or Python's zipfile)",
    )


def _entry_names(fmu_path: Path) -> list[str]:
    if not fmu_path.is_file():
        return []
    with zipfile.ZipFile(fmu_path) as archive:
        return archive.namelist()


def _read_description(fmu_path: Path) -> tuple[ModelDescription, tuple[str, ...]]:
    if not fmu_path.exists():
        raise FmuLoadError(f"FMU file not found: expected an .fmu archive at {fmu_path}")
    unzip.check_regular(fmu_path)  # a FIFO would block, /dev/zero be read without end
    if fmu_path.is_file():
        if not zipfile.is_zipfile(fmu_path):
            raise FmuLoadError(
                f"{fmu_path.name} is not an FMU: expected a zip archive (an .fmu file exported by a "
                f"modelling tool), got a file that is not a zip [{fmu_path}]"
            )
        with zipfile.ZipFile(fmu_path) as archive:
            if "modelDescription.xml" not in archive.namelist():
                raise FmuLoadError(
                    f"{fmu_path.name} is a zip archive but not an FMU: it has no modelDescription.xml at "
                    f"its root; re-export the model as an FMU [{fmu_path}]"
                )
            unzip.check_description_size(fmu_path, archive.getinfo("modelDescription.xml").file_size)
    try:
        return read_model_description(str(fmu_path), validate=True), ()
    except ValidationError as exc:
        # Exporters in the wild bend the standard (e.g. Integer variables declared continuous).
        # Load what can be loaded, and say what is wrong instead of refusing the model.
        problems = tuple(str(p) for p in exc.problems)
        _log.warning(
            "%s: modelDescription.xml breaks the FMI standard in %d place(s), loading it anyway: %s",
            fmu_path.name,
            len(problems),
            "; ".join(problems[:3]),
        )
    except Exception as exc:
        raise FmuLoadError(
            f"{fmu_path.name}: modelDescription.xml cannot be read: {exc}; "
            f"check it with `fmpy validate {fmu_path}` [{fmu_path}]"
        ) from exc
    try:
        return read_model_description(str(fmu_path), validate=False), problems
    except Exception as exc:
        raise FmuLoadError(
            f"{fmu_path.name}: modelDescription.xml is invalid: {'; '.join(problems[:5])} [{fmu_path}]"
        ) from exc


def _default_experiment(md: ModelDescription) -> DefaultExperiment:
    de = md.defaultExperiment
    if de is None:
        return DefaultExperiment()
    return DefaultExperiment(
        start_time_s=_float(de.startTime),
        stop_time_s=_float(de.stopTime),
        step_size_s=_float(de.stepSize),
        tolerance=_float(de.tolerance),
    )


def _float(value: Any) -> float | None:
    if value is None or value == "":
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _variable(v: ModelVariable) -> Variable:
    declared = v.declaredType
    var_type = _TYPE_ALIASES.get(v.type, v.type)
    items: tuple[tuple[str, int], ...] = ()
    if var_type == "Enumeration" and declared is not None:
        items = tuple((item.name, int(item.value)) for item in declared.items)

    def attr(name: str) -> float | None:
        own = getattr(v, name, None)
        if own is None and declared is not None:
            own = getattr(declared, name, None)
        return _float(own)

    unit = v.unit or (declared.unit if declared is not None else None)
    return Variable(
        name=v.name,
        value_reference=int(v.valueReference),
        type=var_type,
        causality=v.causality or "local",
        variability=v.variability or ("continuous" if var_type in ("Float64", "Float32") else "discrete"),
        initial=v.initial,
        start=_start_value(v.start, var_type),
        min=attr("min"),
        max=attr("max"),
        nominal=attr("nominal"),
        unit=unit,
        description=v.description,
        declared_type=declared.name if declared is not None else None,
        enum_items=items,
        is_array=bool(v.dimensions),
        dimensions=_dimensions(v),
        dimension_vrs=tuple(
            int(d.valueReference) if d.start is None and d.valueReference is not None else None
            for d in v.dimensions or ()
        ),
        clock=ClockInfo(str(v.intervalVariability or "unspecified")) if var_type == "Clock" else None,
        clocks=tuple(str(c.name) for c in getattr(v, "clocks", None) or ()),
    )


def _variables(md: ModelDescription, fmu_path: Path) -> dict[str, Variable]:
    variables = {v.name: _variable(v) for v in md.modelVariables}
    clocks = [v for v in variables.values() if v.clock is not None]
    if clocks:  # FMPy reads a clock's interval variability only; the rest comes from the XML
        attributes = _clock_attributes(fmu_path)
        for var in clocks:
            variables[var.name] = replace(var, clock=_clock(var, attributes.get(var.name, {})))
    return variables


def _clock_attributes(fmu_path: Path) -> dict[str, dict[str, str]]:
    if fmu_path.is_file():
        with zipfile.ZipFile(fmu_path) as archive:
            text = archive.read("modelDescription.xml")
    else:
        text = (fmu_path / "modelDescription.xml").read_bytes()
    root = ElementTree.fromstring(text)
    return {str(e.get("name")): dict(e.attrib) for e in root.iterfind("ModelVariables/Clock")}


def _clock(var: Variable, attributes: dict[str, str]) -> ClockInfo:
    return ClockInfo(
        interval_variability=attributes.get("intervalVariability", "unspecified"),
        interval_s=_float(attributes.get("intervalDecimal")),
        shift_s=_float(attributes.get("shiftDecimal")),
        can_be_deactivated=attributes.get("canBeDeactivated") in ("true", "1"),
        priority=int(attributes.get("priority") or 0),
    )


def _dimensions(v: ModelVariable) -> tuple[int, ...]:
    """Array sizes, resolved by FMPy (a dimension may be a structural parameter's start value)."""
    if not v.dimensions:
        return ()
    shape = getattr(v, "shape", None)
    if shape:
        return tuple(int(n) for n in shape)
    return tuple(int(d.start) if d.start is not None else 0 for d in v.dimensions)


def _start_value(start: Any, var_type: str) -> Any:
    if start is None:
        return None
    text = str(start).strip()
    try:
        if var_type in ("Float64", "Float32"):
            return float(text)
        if var_type == "Boolean":
            return text.lower() in ("true", "1")
        if var_type == "String":
            return str(start)
        return int(text)
    except ValueError:
        return text
