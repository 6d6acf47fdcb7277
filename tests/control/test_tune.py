"""``fmu-bridge tune``: the stated objective recomputed independently, the result written back."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from agents.evaluate import baseline_settings, run_episode
from agents.policies import make_policy
from agents.tune import tune
from bridge.cli.main import _load_plugins, app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment import load_experiment
from bridge.experiment.examples import example_experiment


def held_iae(error: np.ndarray, dt: float, duration: float, n_steps: int) -> float:
    """By hand: |e| summed over the samples after each action, the last error held to the end."""
    steps = np.abs(error[1:]) * dt
    missing = round(duration / dt) - n_steps
    return float(np.sum(steps) + missing * abs(error[-1]) * dt)


def test_objective_is_the_mean_held_iae_on_the_training_scenarios() -> None:
    path = example_experiment("dcmotor_tracking")
    result = tune(path, "pid", ["kp", "ki"], iterations=6, seeds=1)
    experiment = load_experiment(path)
    env = FmuEnv(experiment)
    policy = make_policy("pid", baseline_settings(experiment))
    values = []
    try:
        for scenario in experiment.schedule.training:
            trace = run_episode(env, policy, 1000, scenario)
            error = trace.signals["omega_ref"] - trace.signals["omega"]
            values.append(
                held_iae(error, 0.01, 3.0, len(trace.rewards)) + (100.0 if trace.terminated else 0.0)
            )
    finally:
        env.close()
    assert result.start_objective == pytest.approx(np.mean(values), rel=1e-9)
    assert result.start == [2.0, 10.0]
    assert result.scenarios == list(experiment.schedule.training)
    assert len(result.evaluations) >= 6
    assert result.best_objective == min(e["objective"] for e in result.evaluations)
    assert result.best_objective <= result.start_objective


def test_tune_command_writes_the_tuned_experiment(tmp_path: Path) -> None:
    target = tmp_path / "tuned.yaml"
    args = ["tune", str(example_experiment("dcmotor_tracking")), "lqr", "--param", "design.r.voltage"]
    args += ["--iterations", "3", "--seeds", "1", "--write", str(target)]
    _load_plugins()
    outcome = CliRunner().invoke(app, args)
    assert outcome.exit_code == 0, outcome.output
    record = json.loads(target.with_suffix(".tuning.json").read_text())
    tuned = load_experiment(target).evaluation.baselines["lqr"].settings()
    assert tuned["design"]["r"]["voltage"] == pytest.approx(record["best"][0], rel=1e-5)
    assert "held IAE of omega" in record["objective"]


def test_unknown_or_non_numeric_parameter_is_a_clear_error() -> None:
    path = example_experiment("dcmotor_tracking")
    with pytest.raises(ConfigError, match=r"not a value of the baseline.*kp"):
        tune(path, "pid", ["kq"], iterations=1)
    with pytest.raises(ConfigError, match="only positive numbers"):
        tune(path, "pid", ["anti_windup"], iterations=1)
    with pytest.raises(ConfigError, match=r"not in evaluation\.baselines"):
        tune(path, "pd", ["kp"], iterations=1)
