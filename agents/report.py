"""Evaluation outputs: results.csv, results.json, and a Markdown report with PNG plots.

Plots a control engineer can read: every tracked output is drawn with its reference, every
axis says its unit (the FMU's, from its model description), every agent has one colour in every
plot (the same as in the Rerun replay, ``bridge.recording.replay_signals.agent_colour``), and
every signal of the task is plotted (or the set named in ``evaluation.plots``).
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate import EvaluationResult, metric_spec
from agents.metrics import aggregate
from bridge.experiment.config import Experiment
from bridge.recording.replay_signals import REFERENCE_RGB, agent_colours

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
        k
        for k in keys
        if k.endswith((".rmse", ".iae", ".iae_held", ".overshoot_pct", ".effort_sq")) and k not in chosen
    ]
    return chosen[:limit]


def write(
    result: EvaluationResult, out_dir: Path, title: str, experiment: Experiment | None = None
) -> dict[str, Path]:
    """Write the tables and the report; ``experiment`` gives units, tracking pairs and plotted signals."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summary(result)
    paths = {
        "csv": out_dir / "results.csv",
        "json": out_dir / "results.json",
        "report": out_dir / "report.md",
    }
    _write_csv(paths["csv"], result.rows)
    paths["json"].write_text(json.dumps({"episodes": result.rows, "summary": rows}, indent=2, default=_json))
    plots = _plots(result, rows, out_dir, PlotSpec.of(experiment, result))
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


class PlotSpec:
    """What the time-series plots show: tracking pairs, further signals, units, agent colours."""

    def __init__(self, tracking: list[tuple[str, str]], signals: list[str], units: dict[str, str],
                 agents: list[str]) -> None:  # fmt: skip
        self.tracking, self.signals, self.units = tracking, signals, units
        self.colours = {a: tuple(c / 255 for c in rgb) for a, rgb in agent_colours(agents).items()}

    @classmethod
    def of(cls, experiment: Experiment | None, result: EvaluationResult) -> PlotSpec:
        trace = next((t[0] for t in result.traces.values() if t), None)
        known = [n for n in trace.signals if not n.startswith("_")] if trace is not None else []
        tracking = [(o, r) for o, r in metric_spec(experiment).tracking if o in known] if experiment else []
        chosen = list(experiment.evaluation.plots if experiment else [])
        if not chosen and trace is not None:
            inputs = list(trace.inputs)
            outputs = [n for n in known if n not in trace.inputs and n in _outputs(experiment, known)]
            chosen = outputs + inputs
        tracked = {o for o, _ in tracking}
        signals = [n for n in chosen if n not in tracked]
        return cls(tracking, signals, _units(experiment), list(result.agents))

    def label(self, name: str) -> str:
        unit = self.units.get(name)
        return f"{name} [{unit}]" if unit else name


def _outputs(experiment: Experiment | None, known: list[str]) -> list[str]:
    if experiment is None:
        return known
    references = set(experiment.observations.references) | {r for _, r in metric_spec(experiment).tracking}
    for scenario in experiment.scenarios.values():
        references |= set(scenario.references)
    return [n for n in known if n not in references]


def _units(experiment: Experiment | None) -> dict[str, str]:
    if experiment is None:
        return {}
    try:
        from bridge.experiment.validate import resolve_fmu
        from bridge.fmu.description import read_model_info

        info = read_model_info(resolve_fmu(experiment))
    except Exception:  # units are a courtesy: an FMU that cannot be read here leaves them out
        return {}
    return {v.name: v.unit for v in info.variables.values() if v.unit}


def _plots(result: EvaluationResult, rows: list[dict[str, Any]], out_dir: Path, spec: PlotSpec) -> list[Path]:
    try:
        from matplotlib.figure import Figure
    except ImportError:  # plots are optional: the tables carry the numbers
        return []
    paths = []
    metrics = headline_columns(rows, limit=4)
    if metrics:
        fig = Figure(figsize=(4 * len(metrics), 3.2), layout="constrained")
        for ax, metric in zip(fig.subplots(1, len(metrics), squeeze=False)[0], metrics):
            _bars(ax, rows, metric, result.agents, result.scenarios, spec=spec)
        paths.append(out_dir / "metrics.png")
        fig.savefig(paths[-1], dpi=110)
    for scenario in result.scenarios:
        panels = len(spec.tracking) + len(spec.signals)
        if not panels:
            continue
        fig = Figure(figsize=(9, 1.0 + 1.9 * panels), layout="constrained")
        axes = fig.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
        for i, agent in enumerate(result.agents):
            traces = result.traces.get((agent, scenario))
            if traces:
                _series(axes, traces[0], agent, spec, first=i == 0)
        for ax in axes:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="best")
        axes[0].set_title(f"scenario {scenario or 'nominal'}: first episode (seed as in the table)")
        axes[-1].set_xlabel("simulation time [s]")
        paths.append(out_dir / f"trace_{scenario or 'nominal'}.png")
        fig.savefig(paths[-1], dpi=110)
    return paths


def _bars(
    ax: Any,
    rows: list[dict[str, Any]],
    metric: str,
    agents: list[str],
    scenarios: list[str],
    *,
    spec: PlotSpec,
) -> None:
    width = 0.8 / max(1, len(agents))
    for i, agent in enumerate(agents):
        values = [
            next((r.get(metric, np.nan) for r in rows if r["agent"] == agent and r["scenario"] == s), np.nan)
            for s in scenarios
        ]
        ax.bar(np.arange(len(scenarios)) + i * width, values, width, label=agent, color=spec.colours[agent])
    ax.set_xticks(
        np.arange(len(scenarios)) + width * (len(agents) - 1) / 2,
        [s or "-" for s in scenarios],
        rotation=20,
        fontsize=7,
    )
    ax.set_title(metric, fontsize=9)
    ax.set_ylabel(_metric_unit(metric, spec), fontsize=8)
    ax.legend(fontsize=6)


def _metric_unit(metric: str, spec: PlotSpec) -> str:
    """The unit of a metric column such as ``lateral_error.iae`` (IAE: unit x s)."""
    signal, _, kind = metric.rpartition(".")
    unit = spec.units.get(signal)
    if not unit:
        return metric
    per_kind = {
        "iae": f"{unit}.s",
        "iae_held": f"{unit}.s",
        "itae": f"{unit}.s2",
        "ise": f"({unit})2.s",
        "rmse": unit,
        "max_error": unit,
    }
    return f"{metric} [{per_kind.get(kind, unit)}]" if kind in per_kind else metric


def _series(axes: Any, trace: Any, agent: str, spec: PlotSpec, first: bool) -> None:
    t, colour = trace.time_s, spec.colours[agent]
    k = 0
    for output, reference in spec.tracking:
        ax = axes[k]
        if first and reference in trace.signals:
            ax.plot(t, trace.signals[reference], color=np.array(REFERENCE_RGB) / 255, linestyle="--",
                    linewidth=1.2, label=f"reference {reference}")  # fmt: skip
        ax.plot(t, trace.signals[output], color=colour, linewidth=1.2, label=agent)
        ax.set_ylabel(spec.label(output), fontsize=8)
        k += 1
    for name in spec.signals:
        ax = axes[k]
        if name in trace.inputs:
            ax.step(t[:-1], trace.inputs[name], where="post", color=colour, linewidth=1.0, label=agent)
        elif name in trace.signals:
            ax.plot(t, trace.signals[name], color=colour, linewidth=1.0, label=agent)
        ax.set_ylabel(spec.label(name), fontsize=8)
        k += 1
