"""Evaluation outputs: results.csv, results.json, and a Markdown report with PNG plots."""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate import EvaluationResult
from agents.metrics import aggregate

HEADLINE = ("return", "length", "success")


def summary(result: EvaluationResult) -> list[dict[str, Any]]:
    """Mean metrics per (agent, scenario), in the order agents and scenarios were given."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in result.rows:
        groups[(row["agent"], row["scenario"])].append(row)
    out = []
    for (agent, scenario), rows in groups.items():
        metrics = aggregate([{k: v for k, v in r.items() if k not in ("episode", "seed")} for r in rows])
        reasons = sorted({r["reason"] for r in rows if r["reason"]})
        out.append(
            {"agent": agent, "scenario": scenario, "episodes": len(rows), **metrics, "end": ",".join(reasons)}
        )
    return out


def headline_columns(rows: list[dict[str, Any]], limit: int = 6) -> list[str]:
    keys = (
        [k for k in rows[0] if k not in ("agent", "scenario", "episodes", "end", "terminated")]
        if rows
        else []
    )
    chosen = [k for k in HEADLINE if k in keys]
    chosen += [
        k for k in keys if k.endswith((".rmse", ".iae", ".overshoot_pct", ".effort_sq")) and k not in chosen
    ]
    return chosen[:limit]


def write(result: EvaluationResult, out_dir: Path, title: str) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summary(result)
    paths = {
        "csv": out_dir / "results.csv",
        "json": out_dir / "results.json",
        "report": out_dir / "report.md",
    }
    _write_csv(paths["csv"], result.rows)
    paths["json"].write_text(json.dumps({"episodes": result.rows, "summary": rows}, indent=2, default=_json))
    plots = _plots(result, rows, out_dir)
    paths["report"].write_text(_markdown(title, rows, plots, result))
    return paths


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def _json(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(type(value).__name__)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def _markdown(title: str, rows: list[dict[str, Any]], plots: list[Path], result: EvaluationResult) -> str:
    columns = ["agent", "scenario", "episodes", *headline_columns(rows, limit=10), "end"]
    lines = [f"# {title}", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    lines += ["", "Means over episodes; every agent saw the same seeds on the same scenarios.", ""]
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    if result.recordings:
        lines += ["", "Recordings (MCAP):", *[f"- `{p}`" for p in result.recordings]]
    return "\n".join(lines) + "\n"


def _plots(result: EvaluationResult, rows: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    try:
        from matplotlib.figure import Figure
    except ImportError:  # plots are optional: the tables carry the numbers
        return []
    paths = []
    metrics = headline_columns(rows, limit=4)
    if metrics:
        fig = Figure(figsize=(4 * len(metrics), 3.2), layout="constrained")
        for ax, metric in zip(fig.subplots(1, len(metrics), squeeze=False)[0], metrics):
            _bars(ax, rows, metric, result.agents, result.scenarios)
        paths.append(out_dir / "metrics.png")
        fig.savefig(paths[-1], dpi=110)
    for scenario in result.scenarios:
        fig = Figure(figsize=(9, 4.5), layout="constrained")
        axes = fig.subplots(2, 1, sharex=True)
        for agent in result.agents:
            traces = result.traces.get((agent, scenario))
            if traces:
                _series(axes, traces[0], agent)
        axes[0].set_title(f"scenario {scenario or '(mixed)'}: first episode")
        axes[0].legend(fontsize=7)
        axes[1].set_xlabel("simulation time [s]")
        paths.append(out_dir / f"trace_{scenario or 'mixed'}.png")
        fig.savefig(paths[-1], dpi=110)
    return paths


def _bars(ax: Any, rows: list[dict[str, Any]], metric: str, agents: list[str], scenarios: list[str]) -> None:
    width = 0.8 / max(1, len(agents))
    for i, agent in enumerate(agents):
        values = [
            next((r.get(metric, np.nan) for r in rows if r["agent"] == agent and r["scenario"] == s), np.nan)
            for s in scenarios
        ]
        ax.bar(np.arange(len(scenarios)) + i * width, values, width, label=agent)
    ax.set_xticks(
        np.arange(len(scenarios)) + width * (len(agents) - 1) / 2,
        [s or "-" for s in scenarios],
        rotation=20,
        fontsize=7,
    )
    ax.set_title(metric, fontsize=9)
    ax.legend(fontsize=6)


def _series(axes: Any, trace: Any, agent: str) -> None:
    t = trace.time_s
    shown = [n for n in trace.signals if not n.startswith("_")][:3]
    for name in shown:
        if name in trace.inputs:
            continue
        axes[0].plot(t, trace.signals[name], label=f"{agent}: {name}", linewidth=1)
    for name, values in trace.inputs.items():
        axes[1].step(t[:-1], values, where="post", label=f"{agent}: {name}", linewidth=1)
    axes[1].legend(fontsize=7)
