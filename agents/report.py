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

from agents.evaluate import EvaluationResult
from agents.evaluate_cell import metric_spec
from agents.metrics import aggregate
from agents.stats import describe, interval_text, paired_differences
from bridge.experiment.config import Experiment
from bridge.recording.replay_signals import REFERENCE_RGB, agent_colours

HEADLINE = ("return", "length", "success")


def summary(result: EvaluationResult, metric: str = "return") -> list[dict[str, Any]]:
    """Mean metrics per (agent, scenario), in the order agents and scenarios were given, with the
    median of ``metric`` and bootstrap intervals of its median and mean (``agents.stats``)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in result.rows:
        groups[(row["agent"], row["scenario"])].append(row)
    out = []
    for (agent, scenario), rows in groups.items():
        metrics = aggregate([{k: v for k, v in r.items() if k not in ("episode", "seed")} for r in rows])
        reasons = sorted({r["reason"] for r in rows if r["reason"]})
        out.append(
            {
                "agent": agent,
                "scenario": scenario,
                "episodes": len(rows),
                "seeds": _seeds([int(r["seed"]) for r in rows if "seed" in r]),
                **metrics,
                **_spread(rows, metric),
                "end": ",".join(reasons),
            }
        )
    return out


def _spread(rows: list[dict[str, Any]], metric: str) -> dict[str, float]:
    values = [float(r[metric]) for r in rows if isinstance(r.get(metric), int | float)]
    if not values:
        return {}
    stats = describe(values)
    return {
        f"{metric}.median": stats["median"],
        f"{metric}.median_low": stats["median_low"],
        f"{metric}.median_high": stats["median_high"],
        f"{metric}.mean_low": stats["mean_low"],
        f"{metric}.mean_high": stats["mean_high"],
    }


def paired(
    result: EvaluationResult, reference: str | None = None, metric: str = "return"
) -> list[dict[str, Any]]:
    """Paired differences of ``metric`` against ``reference`` (default: the first agent)."""
    if not result.agents or len(result.agents) < 2:
        return []
    return paired_differences(result.rows, reference or result.agents[0], metric)


def spread_cells(row: dict[str, Any], metric: str = "return") -> list[str]:
    """The median of ``metric`` and its interval, and the mean's interval, as table cells."""
    return [
        _fmt(row.get(f"{metric}.median", math.nan)),
        interval_text(row.get(f"{metric}.median_low", math.nan), row.get(f"{metric}.median_high", math.nan)),
        interval_text(row.get(f"{metric}.mean_low", math.nan), row.get(f"{metric}.mean_high", math.nan)),
    ]


def paired_cells(row: dict[str, Any]) -> list[str]:
    return [
        row["agent"],
        row["scenario"],
        str(row["episodes"]),
        _fmt(row["difference"]),
        interval_text(row["low"], row["high"]),
        f"{row['wins']}/{row['losses']}/{row['ties']}",
        row["verdict"],
    ]


SPREAD_COLUMNS = ["median", "median 95% CI", "mean 95% CI"]
PAIRED_COLUMNS = ["agent", "scenario", "episodes", "difference", "95% CI", "wins/losses/ties", "verdict"]


MARGIN_COLUMNS = ["baseline", "point", "radius", "gain margin [dB]", "phase margin [deg]", "stability margin"]


def design_margins(experiment: Experiment, agents: list[str]) -> list[dict[str, Any]]:
    """Stability margins (``bridge.control.margins``) of every lqr/mpc baseline among ``agents``,
    one row per design point: the loop that runs, Kalman filter included."""
    baselines = experiment.evaluation.baselines
    chosen = [a for a in agents if a in baselines and baselines[a].type in ("lqr", "mpc")]
    if not chosen:
        return []
    from agents.evaluate_cell import baseline_settings
    from agents.policies import make_policy
    from bridge.control.margins import margins
    from bridge.env.fmu_env import FmuEnv

    rows = []
    env = FmuEnv(experiment)
    try:
        for name in chosen:
            policy: Any = make_policy(name, baseline_settings(experiment))
            policy.reset(env.task, None)
            controller = policy.controller
            for point, design in zip(controller.points, controller.designs):
                label = f"{controller.spec.schedule.signal}={point:g}" if controller.spec.schedule else "-"
                rows.append({"baseline": name, "point": label, **margins(design).row()})
    finally:
        env.close()
    return rows


def margin_cells(row: dict[str, Any]) -> list[str]:
    return [
        row["baseline"],
        row["point"],
        _fmt(row["closed_loop_radius"]),
        f"{_fmt(row['gain_margin_low_db'])} .. {_fmt(row['gain_margin_high_db'])}",
        _fmt(row["phase_margin_deg"]),
        _fmt(row["stability_margin"]),
    ]


def _seeds(seeds: list[int]) -> str:
    """``1000-1019`` for consecutive seeds, else the list."""
    if not seeds:
        return ""
    if seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return str(seeds[0]) if len(seeds) == 1 else f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


def headline_columns(rows: list[dict[str, Any]], limit: int = 6) -> list[str]:
    keys = (
        [k for k in rows[0] if k not in ("agent", "scenario", "episodes", "seeds", "end", "terminated")]
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
    result: EvaluationResult,
    out_dir: Path,
    title: str,
    experiment: Experiment | None = None,
    *,
    reference: str | None = None,
    metric: str = "return",
) -> dict[str, Path]:
    """Write the tables and the report; ``experiment`` gives units, tracking pairs and plotted signals
    and what the baselines read; ``reference`` and ``metric`` choose the paired comparison."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summary(result, metric)
    pairs = paired(result, reference, metric)
    paths = {
        "csv": out_dir / "results.csv",
        "json": out_dir / "results.json",
        "report": out_dir / "report.md",
    }
    _write_csv(paths["csv"], result.rows)
    margins = design_margins(experiment, result.agents) if experiment is not None else []
    paths["json"].write_text(
        json.dumps(
            {"episodes": result.rows, "summary": rows, "paired": pairs, "margins": margins},
            indent=2,
            default=_json,
        )
    )
    plots = _plots(result, rows, out_dir, PlotSpec.of(experiment, result))
    note = _signals_note(experiment)
    text = _markdown(title, rows, plots, result, pairs=pairs, metric=metric, note=note)
    if margins:
        text += "\n".join(
            [
                "",
                "## Stability margins of the model-based designs",
                "",
                "The loop that runs (the LQR with its Kalman filter; the mpc without active limits), "
                "broken at the plant input, per design point: the closed loop's spectral radius, the gain "
                "interval over which it stays stable, the phase margin and the Nyquist curve's least "
                "distance from -1.",
                "",
                *_table(MARGIN_COLUMNS, [margin_cells(m) for m in margins]),
                "",
            ]
        )
    paths["report"].write_text(text)
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


def _signals_note(experiment: Experiment | None) -> str:
    if experiment is None:
        return ""
    if experiment.evaluation.baseline_signals == "exact":
        return (
            "Baselines read the exact model values (`evaluation.baseline_signals: exact`), "
            "not the agent's sensors."
        )
    noisy = sorted(experiment.noise.observations)
    if not noisy:
        return "Baselines and agents read the same signals (the experiment declares no sensor noise)."
    return (
        f"Baselines read the agent's sensors: the same sensor noise on {', '.join(noisy)} "
        "as the agent's observation."
    )


def _table(columns: list[str], cells: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    return lines + ["| " + " | ".join(row) + " |" for row in cells]


def _markdown(
    title: str,
    rows: list[dict[str, Any]],
    plots: list[Path],
    result: EvaluationResult,
    *,
    pairs: list[dict[str, Any]] | None = None,
    metric: str = "return",
    note: str = "",
) -> str:
    columns = ["agent", "scenario", "episodes", "seeds", *headline_columns(rows, limit=10), "end"]
    lines = [f"# {title}", "", *_table(columns, [[_fmt(r.get(c, "")) for c in columns] for r in rows])]
    lines += ["", "Means over episodes; every agent saw the same seeds on the same scenarios.", ""]
    if note:
        lines += [note, ""]
    lines += [f"## {metric}: medians and 95 % bootstrap intervals", ""]
    spread = [[r["agent"], r["scenario"], str(r["episodes"]), *spread_cells(r, metric)] for r in rows]
    lines += [*_table(["agent", "scenario", "episodes", *SPREAD_COLUMNS], spread), ""]
    if pairs:
        reference = pairs[0]["reference"]
        lines += [
            f"## Paired differences of {metric} against {reference}",
            "",
            f"Per episode (same scenario, same seed): {metric}(agent) - {metric}({reference}); "
            "the mean and its 95 % percentile bootstrap interval; "
            "a verdict only where the interval excludes zero.",
            "",
            *_table(PAIRED_COLUMNS, [paired_cells(p) for p in pairs]),
            "",
        ]
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    if result.recordings:
        lines += ["", "Recordings (MCAP):", *[f"- `{p}`" for p in result.recordings]]
    return "\n".join(lines) + "\n"


class PlotSpec:
    """What the time-series plots show: tracking pairs, further signals, units, agent colours."""

    def __init__(self, tracking: list[tuple[str, str]], signals: list[str], units: dict[str, str],
                 agents: list[str], bounds: dict[str, tuple[float | None, float | None]] | None = None,
                 ) -> None:  # fmt: skip
        self.tracking, self.signals, self.units = tracking, signals, units
        self.bounds = bounds or {}  # termination bounds, drawn as lines
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
        bounds = dict(experiment.termination.bounds) if experiment else {}
        return cls(tracking, signals, _units(experiment), list(result.agents), bounds)

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


ZOOM_SAMPLES = 50  # an input with more samples also gets a panel of its first ones (steps stay readable)


def _plots(result: EvaluationResult, rows: list[dict[str, Any]], out_dir: Path, spec: PlotSpec) -> list[Path]:
    try:
        import matplotlib  # noqa: F401
    except ImportError:  # plots are optional: the tables carry the numbers
        return []
    paths = []
    fig = metrics_figure(rows, result, spec)
    if fig is not None:
        paths.append(out_dir / "metrics.png")
        fig.savefig(paths[-1], dpi=110)
    for scenario in result.scenarios:
        fig = trace_figure(result, scenario, spec)
        if fig is not None:
            paths.append(out_dir / f"trace_{scenario or 'nominal'}.png")
            fig.savefig(paths[-1], dpi=110)
    return paths


def metrics_figure(rows: list[dict[str, Any]], result: EvaluationResult, spec: PlotSpec) -> Any:
    """Bars of the headline metrics per scenario and agent, units on the axes, one legend."""
    from matplotlib.figure import Figure

    metrics = headline_columns(rows, limit=4)
    if not metrics:
        return None
    fig = Figure(figsize=(4 * len(metrics), 3.4), layout="constrained")
    axes = fig.subplots(1, len(metrics), squeeze=False)[0]
    for ax, metric in zip(axes, metrics):
        _bars(ax, rows, metric, result.agents, result.scenarios, spec=spec)
    _one_legend(fig, axes)
    return fig


def trace_figure(result: EvaluationResult, scenario: str, spec: PlotSpec) -> Any:
    """Each agent's first episode: tracked outputs with their references, further signals, inputs
    as steps (with a panel of their first samples when there are many), termination bounds as lines."""
    from matplotlib.figure import Figure

    panels = len(spec.tracking) + len(spec.signals)
    if not panels:
        return None
    first = next((t[0] for a in result.agents if (t := result.traces.get((a, scenario)))), None)
    zooms = [
        n
        for n in spec.signals
        if first is not None and n in first.inputs and len(first.inputs[n]) > ZOOM_SAMPLES
    ]
    fig = Figure(figsize=(9, 1.2 + 1.9 * (panels + len(zooms))), layout="constrained")
    axes = fig.subplots(panels + len(zooms), 1, squeeze=False)[:, 0]
    main, zoomed = axes[:panels], dict(zip(zooms, axes[panels:]))
    for ax in main[1:]:
        ax.sharex(main[0])
    for i, agent in enumerate(result.agents):
        traces = result.traces.get((agent, scenario))
        if traces:
            _series(main, traces[0], agent, spec, first=i == 0)
            for name, ax in zoomed.items():
                trace = traces[0]
                if name in trace.inputs and len(trace.inputs[name]):
                    u = trace.inputs[name]
                    n = min(ZOOM_SAMPLES, len(u))  # an episode may end sooner
                    held = np.append(u[:n], u[n - 1])  # the last sample held to its end
                    ax.step(trace.time_s[: n + 1], held, where="post", color=spec.colours[agent], label=agent)
                    ax.set_ylabel(spec.label(name), fontsize=8)
                    ax.set_title(f"{name}: the first {ZOOM_SAMPLES} samples", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    seed = next(
        (r["seed"] for r in result.rows if r.get("scenario") == scenario and r.get("episode") == 0), None
    )
    main[0].set_title(
        f"scenario {scenario}: each agent's first episode" + (f" (seed {seed})" if seed is not None else "")
    )
    main[-1].set_xlabel("simulation time [s]")
    for ax in zoomed.values():
        ax.set_xlabel("simulation time [s]")
    _one_legend(fig, axes)
    return fig


def _one_legend(fig: Any, axes: Any) -> None:
    """One legend for the figure: every label once, whichever panel drew it."""
    handles: dict[str, Any] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    if handles:
        columns = min(len(handles), 5)
        fig.legend(
            list(handles.values()), list(handles), loc="outside upper center", ncols=columns, fontsize=7
        )


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


_HEADLINE_UNITS = {"return": "sum of rewards", "length": "samples", "success": "fraction of episodes"}


def _metric_unit(metric: str, spec: PlotSpec) -> str:
    """The axis label of a metric column with its unit, e.g. ``lateral_error.iae [m.s]`` (IAE: unit x s)."""
    if metric in _HEADLINE_UNITS:
        return f"{metric} [{_HEADLINE_UNITS[metric]}]"
    signal, _, kind = metric.rpartition(".")
    unit = spec.units.get(signal)
    fixed = {"overshoot_pct": "%", "violations": "samples", "violation_time_s": "s", "rise_time_s": "s",
             "settling_time_s": "s"}  # fmt: skip
    if kind in fixed:
        return f"{metric} [{fixed[kind]}]"
    if not unit:
        return f"{metric} [{signal} units]" if signal else metric
    per_kind = {
        "iae": f"{unit}.s",
        "iae_held": f"{unit}.s",
        "itae": f"{unit}.s2",
        "ise": f"({unit})2.s",
        "rmse": unit,
        "max_error": unit,
        "effort_abs": f"{unit}.samples",
        "effort_sq": f"({unit})2.samples",
        "total_variation": unit,
        "steady_state_error": unit,
    }
    return f"{metric} [{per_kind.get(kind, unit)}]"


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
        if first:
            _bound_lines(ax, output, spec)
        k += 1
    for name in spec.signals:
        ax = axes[k]
        if name in trace.inputs:
            ax.step(t[:-1], trace.inputs[name], where="post", color=colour, linewidth=1.0, label=agent)
        elif name in trace.signals:
            ax.plot(t, trace.signals[name], color=colour, linewidth=1.0, label=agent)
        ax.set_ylabel(spec.label(name), fontsize=8)
        if first:
            _bound_lines(ax, name, spec)
        k += 1


def _bound_lines(ax: Any, name: str, spec: PlotSpec) -> None:
    for bound in spec.bounds.get(name, (None, None)):
        if bound is not None:
            ax.axhline(float(bound), color="0.35", linestyle=":", linewidth=1.0, label="termination bound")
