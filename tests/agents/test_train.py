"""Short, real SB3 training runs: run directories, checkpoints, resume, residual, normalisation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from agents.evaluate import evaluate
from agents.policies import Sb3Policy
from agents.train import train
from bridge.cli.main import _load_plugins, app
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment

pytestmark = pytest.mark.slow
CARTPOLE = example_experiment("cartpole_balance")
MOTOR = example_experiment("dcmotor_tracking")


def test_training_writes_a_complete_run_directory(tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = train(
        CARTPOLE,
        overrides={
            "timesteps": 2048,
            "n_envs": 2,
            "checkpoint_every": 1024,
            "eval_every": 1024,
            "eval_episodes": 2,
        },
        run_dir=run,
        progress=False,
    )
    assert result.timesteps >= 2048
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "done" and info["algo"] == "PPO" and info["seed"] == 0
    assert len(info["fmu_sha256"]) == 64 and "stable-baselines3" in info["packages"]
    assert info["timesteps"] == result.timesteps and info["wall_time_s"] > 0
    assert (run / "experiment.yaml").read_text() == CARTPOLE.read_text()
    assert (run / "model.zip").is_file() and (run / "best_model.zip").is_file()
    assert sorted(p.name for p in (run / "checkpoints").iterdir())[:1] == ["rl_model_1024_steps.zip"]
    evaluations = np.load(run / "evaluations.npz")
    assert list(evaluations["timesteps"]) == [1024, 2048]
    assert (run / "logs" / "progress.csv").read_text().count("\n") >= 2
    assert any(p.name.startswith("events.out.tfevents") for p in (run / "logs").iterdir())
    policy = Sb3Policy(run)
    assert policy.run["algo"] == "PPO"
    rows = evaluate([str(run)], CARTPOLE, episodes=2).rows
    assert len(rows) == 2 and all(r["length"] >= 1 for r in rows)


def test_resume_continues_the_step_count(tmp_path: Path) -> None:
    run = tmp_path / "run"
    first = train(CARTPOLE, overrides={"timesteps": 1024, "n_envs": 2}, run_dir=run, progress=False)
    second = train(CARTPOLE, overrides={"timesteps": 1024}, resume=run, progress=False)
    assert second.timesteps >= first.timesteps + 1024
    info = json.loads((run / "run.json").read_text())
    assert info["timesteps"] == second.timesteps and info["resumed"][0]["at"] == first.timesteps


def test_resume_keeps_evaluating_and_best_model_follows(tmp_path: Path) -> None:
    """--resume evaluates on schedule; best_model.zip is replaced only by a better evaluation; agent run
    names the checkpoint it deploys with its evaluation."""
    from agents.deploy import deployed_checkpoint

    run = tmp_path / "run"
    settings = {"timesteps": 1024, "n_envs": 2, "eval_every": 512, "eval_episodes": 2}
    train(CARTPOLE, overrides=settings, run_dir=run, progress=False)
    with np.load(run / "evaluations.npz") as data:
        first = list(data["timesteps"])
        best_before = float(data["results"].mean(axis=1).max())
    assert first == [512, 1024]
    stamp = (run / "best_model.zip").stat().st_mtime_ns
    train(CARTPOLE, overrides={"timesteps": 2048}, resume=run, progress=False)
    with np.load(run / "evaluations.npz") as data:
        steps, means = list(data["timesteps"]), data["results"].mean(axis=1)
    assert steps[:2] == first and steps[2:] == [1536, 2048, 2560, 3072]  # the old ones kept, four new
    improved = float(means[2:].max()) > best_before
    assert ((run / "best_model.zip").stat().st_mtime_ns != stamp) == improved
    text = deployed_checkpoint(run, "torch")
    best = int(np.argmax(means))
    assert str(run / "best_model.zip") in text
    assert f"mean reward {means[best]:.1f} at step {steps[best]:,}" in text


def test_residual_over_pid_with_normalised_observations(tmp_path: Path) -> None:
    run = tmp_path / "residual"
    overrides = {
        "algo": "PPO",
        "timesteps": 1024,
        "n_envs": 2,
        "hyperparams": {"n_steps": 256, "batch_size": 64},
        "residual": {"baseline": "pid", "scale": 6.0},
        "normalize": True,
        "eval_every": 100_000,
    }
    train(MOTOR, overrides=overrides, run_dir=run, progress=False)
    info = json.loads((run / "run.json").read_text())
    assert info["residual"]["baseline"] == "pid" and info["residual"]["config"]["kp"] == 2.0
    assert (run / "vecnormalize.pkl").is_file()
    policy = Sb3Policy(run)
    assert policy._obs_rms is not None
    rows = evaluate([str(run), "pid"], MOTOR, scenarios=["step_up"], episodes=1).rows
    residual, pid = rows[0], rows[1]
    # an untrained residual stays close to its PID (a correction of at most 6 V)
    assert abs(residual["omega.rmse"] - pid["omega.rmse"]) < 0.5 * pid["omega.rmse"]


def test_bad_hyperparameter_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"training\.hyperparams: .*n_stepz"):
        train(
            CARTPOLE,
            overrides={"timesteps": 64, "hyperparams": {"n_stepz": 3}},
            run_dir=tmp_path / "r",
            progress=False,
        )
    with pytest.raises(ConfigError, match=r"training\.algo"):
        train(CARTPOLE, overrides={"algo": "XYZ"}, run_dir=tmp_path / "s", progress=False)


def test_train_and_compare_from_the_command_line(tmp_path: Path) -> None:
    runs = []
    for seed in (1, 2):
        run = tmp_path / f"run{seed}"
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "bridge.cli",
                "train",
                str(CARTPOLE),
                "--timesteps",
                "1024",
                "--n-envs",
                "2",
                "--seed",
                str(seed),
                "--vec",
                "subproc",
                "--run-dir",
                str(run),
                "--no-progress",
            ],
            capture_output=True,
            text=True,
            timeout=600,
            check=False,
            env={**os.environ, "COLUMNS": "200"},
        )
        assert result.returncode == 0, result.stderr[-2000:]
        assert "trained" in result.stdout and str(run) in result.stdout
        runs.append(run)
    _load_plugins()
    out = CliRunner().invoke(
        app, ["compare", *map(str, runs), "--plot", str(tmp_path / "curves.png")], env={"COLUMNS": "200"}
    )
    assert out.exit_code == 0, out.output
    assert "run1" in out.output and "run2" in out.output and (tmp_path / "curves.png").is_file()


def test_eval_env_has_the_training_env_type_so_sb3_does_not_warn() -> None:
    """SB3's EvalCallback warns 'Training and eval env are not of the same type' unless
    isinstance(training_env, type(eval_env)); subproc and remote (VecMonitor) training must pass."""
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecMonitor

    from agents.settings import TrainingSettings
    from agents.train import build_eval_env, build_vec_env
    from bridge.experiment.config import load_experiment

    path, experiment = CARTPOLE, load_experiment(CARTPOLE)
    settings = TrainingSettings.from_experiment(experiment, {"vec": "subproc", "n_envs": 2})
    train_env = build_vec_env(settings, experiment, path, None, 0)
    eval_env = build_eval_env(train_env, settings, experiment, path, None)
    try:
        assert isinstance(train_env, SubprocVecEnv) and isinstance(train_env, type(eval_env))
    finally:
        eval_env.close()
        train_env.close()
    plain = TrainingSettings.from_experiment(experiment, {"n_envs": 1})
    monitored = VecMonitor(build_vec_env(plain, experiment, path, None, 0))
    remote_like = build_eval_env(monitored, settings, experiment, path, None)
    assert isinstance(monitored, type(remote_like)) and type(remote_like) is VecMonitor
    remote_like.close()
    monitored.close()
