"""`fmu-bridge sweep` on two Ray nodes on 127.0.0.1: seeds x a hyperparameter grid, each point a Ray
task that trains (SB3 PPO) and evaluates; the report equals the single-machine sweep's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")
pytest.importorskip("stable_baselines3")

from agents.sweep import parse_grid, points, sweep, write_report
from bridge.experiment.examples import example_experiment

GRID = ["n_steps=32", "batch_size=32", "n_epochs=1", "learning_rate=0.001,0.01"]


def test_sweep_on_ray_equals_the_single_machine_sweep(ray_cluster: Any, tmp_path: Path) -> None:
    experiment = example_experiment("cartpole_balance")
    reports = {}
    for engine in ("local", "ray"):
        out = tmp_path / engine
        todo = points(
            experiment, seeds=[0, 1], grid=parse_grid(GRID), out=out, timesteps=64, n_envs=1, eval_episodes=2
        )
        rows = sweep(todo, engine=engine)
        assert len(rows) == 4 and all((out / "runs" / row["run"] / "model.zip").is_file() for row in rows)
        paths = write_report(rows, out, title="sweep")
        reports[engine] = {kind: path.read_text() for kind, path in paths.items()}
    assert reports["ray"] == reports["local"]  # sweep.csv, sweep.json, sweep.md
    assert "learning_rate" in reports["local"]["csv"].splitlines()[0]
