"""compare: runs of one configuration over several seeds get one row with their spread."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agents.compare import compare_runs, over_seeds
from agents.stats import bootstrap_interval


def _run(root: Path, name: str, seed: int, lr: float, final: float) -> Path:
    run = root / name
    run.mkdir()
    info = {
        "experiment": "cartpole_balance",
        "algo": "PPO",
        "seed": seed,
        "status": "finished",
        "timesteps": 1000,
        "wall_time_s": 10.0,
        "settings": {"algo": "PPO", "seed": seed, "timesteps": 1000, "hyperparams": {"learning_rate": lr}},
        "residual": None,
    }
    (run / "run.json").write_text(json.dumps(info))
    np.savez(
        run / "evaluations.npz",
        timesteps=np.array([500, 1000]),
        results=np.array([[1.0, 3.0], [final, final]]),
    )
    return run


def test_seeds_of_one_configuration_are_summarised_and_other_settings_kept_apart(tmp_path: Path) -> None:
    finals = [100.0, 140.0, 120.0]
    runs = [_run(tmp_path, f"ppo-s{i}", i, 3e-4, f) for i, f in enumerate(finals)]
    runs.append(_run(tmp_path, "ppo-lr-high", 0, 1e-3, 50.0))  # another configuration: its own (single) row
    rows, _ = compare_runs(runs)
    (group,) = over_seeds(rows, [r["setup"] for r in rows])
    assert group["n"] == 3 and group["seeds"] == "0,1,2"
    assert group["last_mean"] == pytest.approx(120.0)
    assert group["last_std"] == pytest.approx(float(np.std(finals, ddof=1)))
    assert (group["last_min"], group["last_max"]) == (100.0, 140.0)
    assert (group["last_low"], group["last_high"]) == pytest.approx(bootstrap_interval(finals))
    assert "ppo-lr-high" not in group["runs"]
