"""The slow plant (``models/slow_plant``) through the agents' paths: SB3 training with subprocess
workers and ``evaluate`` with worker processes, with no setting for its slowness."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agents.evaluate import evaluate
from agents.train import train
from tests.slow_plant import slow_experiment


@pytest.mark.slow  # trains (worker processes, a few seconds of slow steps)
@pytest.mark.integration
def test_sb3_trains_on_slow_plants_in_worker_processes(tmp_path: Path) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.2, init_delay_s=1.0, duration_s=0.4)
    overrides = {
        "timesteps": 16,
        "n_envs": 2,
        "vec": "subproc",
        "eval_every": 100_000,
        "hyperparams": {"n_steps": 8, "batch_size": 8, "n_epochs": 1},
    }
    result = train(path, overrides=overrides, run_dir=tmp_path / "run", progress=False)
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["status"] == "done" and result.timesteps == 16, info


@pytest.mark.integration  # worker processes
def test_evaluate_with_workers_runs_slow_plant_episodes(tmp_path: Path) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.1, init_delay_s=0.5, duration_s=0.3)
    result = evaluate(["zero"], path, episodes=4, workers=2)
    assert [row["episode"] for row in result.rows] == [0, 1, 2, 3]
    assert all(row["length"] == 3 and row["reason"] == "time" for row in result.rows), result.rows
