"""A model summary for people (a table) and programs (JSON): what ``fmu-bridge inspect`` shows."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bridge.fmu import ModelInfo, read_model_info

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
