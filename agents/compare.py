"""``fmu-bridge compare``: training runs side by side, from their run directories."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from agents.run_state import read_run
from agents.stats import describe
from bridge.errors import ConfigError


def load_evaluations(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(timesteps, mean episode return) of the periodic evaluations during training."""
    file = run_dir / "evaluations.npz"
    if not file.is_file():
        return np.zeros(0), np.zeros(0)
    data = np.load(file)
    return data["timesteps"], data["results"].mean(axis=1)


def same_setup(info: dict[str, Any]) -> str:
    """What makes two runs repeats of one configuration: everything in run.json but the seed."""
    settings = {k: v for k, v in (info.get("settings") or {}).items() if k != "seed"}
    return json.dumps(
        {
            "experiment": info.get("experiment"),
            "algo": info.get("algo"),
            "settings": settings,
            "residual": info.get("residual"),
        },
        sort_keys=True,
        default=str,
    )


def over_seeds(rows: list[dict[str, Any]], setups: list[str]) -> list[dict[str, Any]]:
    """One row per configuration trained with more than one seed: the spread of the final and best
    evaluation returns over its seeds (mean, its bootstrap interval, standard deviation, range)."""
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row, setup in zip(rows, setups):
        groups[setup].append(row)
    out = []
    for members in groups.values():
        if len(members) < 2:
            continue
        last = [float(r["last_eval"]) for r in members]
        best = [float(r["best_eval"]) for r in members]
        stats = describe(last)
        out.append(
            {
                "runs": ",".join(r["run"] for r in members),
                "algo": members[0]["algo"],
                "seeds": ",".join(str(r["seed"]) for r in members),
                "n": len(members),
                "last_mean": stats["mean"],
                "last_low": stats["mean_low"],
                "last_high": stats["mean_high"],
                "last_std": stats["std"],
                "last_min": float(np.nanmin(last)) if not all(math.isnan(v) for v in last) else math.nan,
                "last_max": float(np.nanmax(last)) if not all(math.isnan(v) for v in last) else math.nan,
                "best_mean": describe(best)["mean"],
            }
        )
    return out


def compare_runs(runs: list[Path]) -> tuple[list[dict[str, Any]], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """One row per run (settings, time, evaluation returns) and each run's learning curve."""
    rows, curves = [], {}
    for run in runs:
        info_file = run / "run.json"
        if not info_file.is_file():
            raise ConfigError(f"{run} is not a run directory (no run.json); `fmu-bridge train` writes them")
        info = read_run(run)  # a run whose training process is gone is "interrupted"
        steps, returns = load_evaluations(run)
        curves[run.name] = (steps, returns)
        wall = float(info.get("wall_time_s", math.nan))
        timesteps = int(info.get("timesteps", 0))
        rows.append(
            {
                "run": run.name,
                "algo": info.get("algo", "?"),
                "seed": info.get("seed", "?"),
                "timesteps": timesteps,
                "wall_time_s": wall,
                "steps_per_s": timesteps / wall if wall and wall > 0 else math.nan,
                "best_eval": float(returns.max()) if returns.size else math.nan,
                "last_eval": float(returns[-1]) if returns.size else math.nan,
                "status": info.get("status", "?"),
                "setup": same_setup(info),
            }
        )
    return rows, curves


def plot_curves(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4), layout="constrained")
    ax = fig.subplots()
    for name, (steps, returns) in curves.items():
        ax.plot(steps, returns, marker="o", markersize=3, label=name)
    ax.set_xlabel("timesteps")
    ax.set_ylabel("mean evaluation return")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
