"""A model summary for people (a table) and programs (JSON): what ``fmu-bridge inspect`` shows."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

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
    if not dims:
        return str(var["type"])
    sized_by = var.get("sized_by") or [None] * len(dims)
    shown = [f"{by}={n}" if by else str(n) for n, by in zip(dims, sized_by, strict=False)]
    return f"{var['type']}[{','.join(shown)}]"


def interfaces_text(info: dict[str, Any]) -> str:
    names = ["SE (scheduled execution)" if name == "SE" else name for name in info["interfaces"]]
    if info.get("has_event_mode"):
        names = ["CS (event mode)" if name == "CS" else name for name in names]
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


def print_rows(
    console: Console, columns: Sequence[str], rows: Sequence[Sequence[str]], title: str = ""
) -> None:
    """A table where it fits a terminal, else a plain list: names and paths are never cut.

    Piped output (and any terminal narrower than the table) gets one block per row: the first
    column on its own line, the other non-empty cells below it as ``column: value``.
    """
    widths = [max([len(c), *(len(r[i]) for r in rows if i < len(r))]) for i, c in enumerate(columns)]
    if console.is_terminal and sum(widths) + 3 * len(columns) + 1 <= console.width:
        table = Table(*columns, title=title or None)
        for column in table.columns:
            column.no_wrap = True
        for row in rows:
            table.add_row(*(escape(cell) for cell in row))
        console.print(table)
        return
    if title:
        console.print(title, markup=False, highlight=False, soft_wrap=True)
    for row in rows:
        rest = [f"{c}: {v}" for c, v in zip(columns[1:], row[1:]) if v]
        console.print(row[0], markup=False, highlight=False, soft_wrap=True)
        if rest:
            console.print("  " + "  ".join(rest), markup=False, highlight=False, soft_wrap=True)
