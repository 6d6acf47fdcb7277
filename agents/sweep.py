"""Sweeps: training runs over seeds and a grid of hyperparameters, each run then evaluated.

Every grid point is one unit that runs the single-machine code unchanged: ``train`` with the point's
seed and hyperparameters (over the experiment's ``training.hyperparams``), then ``evaluate`` of the
trained model over fixed evaluation seeds. Units run here one after the other
(``engine="local"``) or as Ray tasks on a cluster (``engine="ray"``, ``agents.ray_engine``, retried
when a worker or node dies); either way the report (``sweep.csv``, ``sweep.json``, ``sweep.md``)
is the same for the same seeds. Each unit uses one torch thread, as a Ray task of one CPU does, so
that the runs are bit-identical wherever they run.

Run folders go to ``OUT/runs/``: on a cluster, that is the worker's disk unless OUT is shared.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment


@dataclass(frozen=True)
class SweepPoint:
    experiment: Path
    version: str | None
    seed: int
    hyperparams: tuple[tuple[str, Any], ...]  # this point's grid values
    timesteps: int | None
    n_envs: int | None
    eval_episodes: int
    eval_seed: int
    run_dir: Path


def parse_grid(items: Sequence[str]) -> dict[str, list[Any]]:
    """``["learning_rate=0.001,0.0003", "n_steps=32,64"]`` -> the grid (values read as YAML)."""
    grid: dict[str, list[Any]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        if not sep or not key.strip() or not values.strip():
            raise ConfigError(f"--grid {item!r}: expected NAME=V1,V2,... (e.g. learning_rate=0.001,0.0003)")
        grid[key.strip()] = [yaml.safe_load(v) for v in values.split(",")]
    return grid


def points(
    experiment: Path,
    *,
    seeds: Sequence[int],
    grid: Mapping[str, Sequence[Any]],
    out: Path,
    version: str | None = None,
    timesteps: int | None = None,
    n_envs: int | None = None,
    eval_episodes: int = 5,
    eval_seed: int = 1000,
) -> list[SweepPoint]:
    """Every (hyperparameter set, seed) of the sweep, in report order."""
    if not seeds:
        raise ConfigError("a sweep needs at least one seed (e.g. --seeds 0,1,2)")
    if eval_episodes < 1:
        raise ConfigError(f"eval_episodes must be at least 1, got {eval_episodes}")
    load_experiment(experiment, version=version)  # a bad file fails here, not in every task
    keys = list(grid)
    combos = list(itertools.product(*(grid[k] for k in keys))) or [()]
    result = []
    for n, combo in enumerate(combos):
        for seed in seeds:
            result.append(
                SweepPoint(
                    experiment=experiment.resolve(),
                    version=version,
                    seed=int(seed),
                    hyperparams=tuple(zip(keys, combo)),
                    timesteps=timesteps,
                    n_envs=n_envs,
                    eval_episodes=eval_episodes,
                    eval_seed=eval_seed,
                    run_dir=(out / "runs" / f"p{n}-seed{seed}").resolve(),
                )
            )
    return result


def run_point(point: SweepPoint) -> dict[str, Any]:
    """One unit: train with the point's settings, evaluate the model; the report's row."""
    import torch

    from agents.evaluate import evaluate
    from agents.train import train

    torch.set_num_threads(1)  # the same arithmetic here and in a one-CPU Ray task
    experiment = load_experiment(point.experiment, version=point.version)
    hyperparams = {**experiment.training.hyperparams, **dict(point.hyperparams)}
    overrides = {
        "seed": point.seed,
        "hyperparams": hyperparams,
        "timesteps": point.timesteps,
        "n_envs": point.n_envs,
    }
    trained = train(
        point.experiment, overrides=overrides, run_dir=point.run_dir, version=point.version, progress=False
    )
    evaluation = evaluate(
        [f"agent={trained.run_dir}"],
        point.experiment,
        version=point.version,
        episodes=point.eval_episodes,
        seed=point.eval_seed,
    )
    returns = [float(row["return"]) for row in evaluation.rows]
    lengths = [float(row["length"]) for row in evaluation.rows]
    mean = sum(returns) / len(returns)
    return {
        "seed": point.seed,
        **dict(point.hyperparams),
        "mean_return": mean,
        "std_return": math.sqrt(sum((r - mean) ** 2 for r in returns) / len(returns)),
        "mean_length": sum(lengths) / len(lengths),
        "timesteps": trained.timesteps,
        "run": point.run_dir.name,
    }


def sweep(
    sweep_points: Sequence[SweepPoint], *, engine: str = "local", ray_address: str | None = None
) -> list[dict[str, Any]]:
    """The report's rows, one per point, in the points' order."""
    if engine == "local":
        return [run_point(p) for p in sweep_points]
    if engine == "ray":
        from agents.ray_engine import licence_resources, ray_map

        if not sweep_points:
            return []
        # a run opens n_envs training instances and one evaluation instance at once
        first = sweep_points[0]
        experiment = load_experiment(first.experiment, version=first.version)
        n_envs = max(p.n_envs or experiment.training.n_envs for p in sweep_points)
        resources = licence_resources(experiment, n_envs + 1)
        return ray_map(run_point, sweep_points, address=ray_address, resources=resources)
    raise ConfigError(f"engine must be 'local' or 'ray', got {engine!r}")


def write_report(rows: Sequence[Mapping[str, Any]], out: Path, title: str) -> dict[str, Path]:
    """``sweep.csv``, ``sweep.json`` and ``sweep.md`` (rows best mean return first) in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "sweep.csv", "json": out / "sweep.json", "report": out / "sweep.md"}
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with paths["csv"].open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    paths["json"].write_text(json.dumps({"title": title, "runs": list(rows)}, indent=2))
    ranked = sorted(rows, key=lambda r: -float(r["mean_return"]))
    lines = [f"# {title}", "", "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_cell(row.get(k)) for k in keys) + " |" for row in ranked]
    paths["report"].write_text("\n".join(lines) + "\n")
    return paths


def _cell(value: Any) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)
