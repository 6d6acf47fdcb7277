"""A model summary for people (a table) and programs (JSON): what ``fmu-bridge inspect`` shows."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bridge.fmu import read_model_info
from bridge.fmu.vocab import summary_of

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
    return summary_of(read_model_info(path))


def type_cell(var: dict[str, Any]) -> str:
    """``Float64`` for a scalar, ``Float64[2,3]`` for an FMI 3.0 array (elements ``y[1,1]``..``y[2,3]``)."""
    dims = var.get("dimensions")
    return f"{var['type']}[{','.join(map(str, dims))}]" if dims else str(var["type"])


def interfaces_text(info: dict[str, Any]) -> str:
    names = list(info["interfaces"])
    if info.get("scheduled_execution"):
        names.append("scheduled execution (not run by fmu-bridge)")
    return ", ".join(names) or "none"


def clock_lines(info: dict[str, Any]) -> list[str]:
    """One line per clock: name, interval variability, interval and shift where declared."""
    lines = []
    for var in info["variables"]:
        clock = var.get("clock")
        if clock is None:
            continue
        parts = [f"{var['name']} ({var['causality']}): {clock['interval_variability']}"]
        if clock["interval_s"] is not None:
            parts.append(f"interval {clock['interval_s']:g} s")
        if clock["shift_s"]:
            parts.append(f"shift {clock['shift_s']:g} s")
        lines.append(", ".join(parts))
    return lines
