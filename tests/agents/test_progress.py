"""Progress that tells the truth: ``train`` announces SB3's rounded-up step count and its bar counts
the steps that really run, with env steps per second of wall time; ``evaluate`` reports episodes
done of the total."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents.evaluate import evaluate
from agents.train import train
from bridge.experiment.examples import example_experiment

CARTPOLE = example_experiment("cartpole_balance")


def test_train_announces_the_rounded_up_steps_and_its_bar_counts_them(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    overrides = {
        "timesteps": 100,
        "n_envs": 1,
        "eval_every": 100_000,
        "hyperparams": {"n_steps": 64, "batch_size": 64},
    }
    result = train(CARTPOLE, overrides=overrides, run_dir=tmp_path / "run", progress=True)
    err = capfd.readouterr().err
    assert "training 128 steps: 100 rounded up to whole rollouts of 64 steps x 1 envs" in err
    assert "128/128 steps" in err and "env-steps/s" in err and "ETA" in err
    assert "/100 " not in err  # the bar's total is what really runs
    assert result.timesteps == 128 == json.loads((tmp_path / "run" / "run.json").read_text())["timesteps"]


def test_train_says_nothing_when_nothing_is_rounded(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    overrides = {
        "timesteps": 128,
        "n_envs": 2,
        "eval_every": 100_000,
        "hyperparams": {"n_steps": 32, "batch_size": 64},
    }
    train(CARTPOLE, overrides=overrides, run_dir=tmp_path / "run", progress=False)
    assert "rounded up" not in capfd.readouterr().err


@pytest.mark.parametrize("workers", [1, 2])
def test_evaluate_reports_episodes_done_of_the_total(workers: int) -> None:
    seen: list[tuple[int, int]] = []
    evaluate(
        ["random", "zero=constant:10"],
        CARTPOLE,
        episodes=3,
        workers=workers,
        progress=lambda d, t: seen.append((d, t)),
    )
    assert seen[0] == (0, 6) and seen[-1] == (6, 6)
    assert all(t == 6 for _, t in seen) and [d for d, _ in seen] == sorted(d for d, _ in seen)
    if workers == 1:
        assert [d for d, _ in seen] == list(range(7))  # after every episode


def test_evaluate_from_the_command_line_shows_the_bar(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "evaluate", "random", "--config", str(CARTPOLE),
         "--episodes", "2", "--no-record", "--out", str(tmp_path / "eval")],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False, env=dict(os.environ),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert "2/2 episodes" in " ".join(result.stderr.split())


def test_the_eta_follows_the_average_rate_through_rollouts_and_updates() -> None:
    """PPO's pattern on a clock we drive: 1,000 steps in the first second (a rollout), then 9 s of
    learning without a step. The ETA is the 9,000 steps left at the run's average speed so far
    (250, 143, then 100 steps/s), not the rollout's 1,000 steps/s nor the update's none."""
    from rich.progress import Progress

    from agents.progress import SteadyEta

    now = [0.0]
    bar = Progress(SteadyEta(), get_time=lambda: now[0], auto_refresh=False)
    task = bar.add_task("train", total=10_000)
    column = SteadyEta()
    assert column.render(bar.tasks[0]).plain == "-:--:--"  # no speed yet
    seen = []
    for t in (0.25, 0.5, 0.75, 1.0):  # the rollout: 250 steps every 0.25 s
        now[0] = t
        bar.update(task, completed=int(1000 * t))
    for t in (4.0, 7.0, 10.0):  # the update: no steps
        now[0] = t
        bar.update(task, completed=1000)
        seen.append(column.render(bar.tasks[0]).plain)
    assert seen == ["0:00:36", "0:01:03", "0:01:30"]
