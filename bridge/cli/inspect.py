"""A model summary for people (a table) and programs (JSON): what ``fmu-bridge inspect`` shows."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bridge.fmu import DefaultExperiment, ModelInfo, Variable, read_model_info

VARIABLE_COLUMNS = (
    "name",
    "causality",
    "variability",
    "type",
    "start",
    "min",
    "max",
    "nominal",
    "unit",
    "description",
)


def summary(path: str | Path) -> dict[str, Any]:
    """A JSON-ready description of an FMU: version, interfaces, experiment, platforms, variables."""
    info = read_model_info(path)
    return summary_of(info)


def summary_of(info: ModelInfo) -> dict[str, Any]:
    de = info.default_experiment
    return {
        "path": str(info.path),
        "model_name": info.model_name,
        "guid": info.guid,
        "fmi_version": info.fmi_version,
        "interfaces": [i.upper() for i in info.interfaces],
        "generation_tool": info.generation_tool,
        "description": info.description,
        "default_experiment": {
            "start_time_s": de.start_time_s,
            "stop_time_s": de.stop_time_s,
            "step_size_s": de.step_size_s,
            "tolerance": de.tolerance,
        },
        "platforms": list(info.platforms),
        "can_get_set_state": {k.upper(): v for k, v in info.can_get_set_state.items()},
        "continuous_states": info.number_of_states,
        "event_indicators": info.number_of_event_indicators,
        "problems": list(info.problems),
        "variables": [
            {
                "name": v.name,
                "causality": v.causality,
                "variability": v.variability,
                "type": v.type,
                "start": v.start,
                "min": v.min,
                "max": v.max,
                "nominal": v.nominal,
                "unit": v.unit,
                "description": v.description,
                **({"enumeration": dict(v.enum_items)} if v.enum_items else {}),
            }
            for v in info.variables.values()
        ],
    }


def info_from_summary(data: dict[str, Any]) -> ModelInfo:
    """A ModelInfo rebuilt from ``summary_of`` output (what a remote node reports about its FMU)."""
    de = data.get("default_experiment", {})
    variables = {}
    for v in data["variables"]:
        items = tuple((str(k), int(x)) for k, x in (v.get("enumeration") or {}).items())
        variables[v["name"]] = Variable(
            name=v["name"],
            value_reference=-1,
            type=v["type"],
            causality=v["causality"],
            variability=v["variability"],
            initial=None,
            start=v.get("start"),
            min=v.get("min"),
            max=v.get("max"),
            nominal=v.get("nominal"),
            unit=v.get("unit"),
            description=v.get("description"),
            enum_items=items,
        )
    return ModelInfo(
        path=Path(data.get("path", "remote.fmu")),
        fmi_version=data["fmi_version"],
        model_name=data["model_name"],
        guid=data.get("guid", ""),
        interfaces=tuple(i.lower() for i in data["interfaces"]),  # type: ignore[misc]
        model_identifiers={},
        default_experiment=DefaultExperiment(
            start_time_s=de.get("start_time_s"),
            stop_time_s=de.get("stop_time_s"),
            step_size_s=de.get("step_size_s"),
            tolerance=de.get("tolerance"),
        ),
        platforms=tuple(data.get("platforms", ())),
        variables=variables,
        can_get_set_state={k.lower(): bool(x) for k, x in data.get("can_get_set_state", {}).items()},
        number_of_states=int(data.get("continuous_states", 0)),
        number_of_event_indicators=int(data.get("event_indicators", 0)),
        generation_tool=data.get("generation_tool"),
        description=data.get("description"),
    )
