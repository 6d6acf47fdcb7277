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
