"""`train --engine rllib` on two Ray nodes on 127.0.0.1: PPO over env runners that each host a batch
env of K FMU instances; an env runner killed with SIGKILL is restarted by Ray and training goes on
to the end, with checkpoints in the run folder."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray.rllib")

from agents.rllib_train import train_rllib
from bridge.experiment.examples import example_experiment

K = 4
N_STEPS = 32


def experiment(tmp_path: Path) -> Path:
    text = example_experiment("cartpole_balance").read_text()
    training = text[text.index("\ntraining:") :]
    text = text.replace(training, "\n")  # the example's own training section, replaced below
    path = tmp_path / "cartpole.yaml"
    path.write_text(
        text
        + "training:\n  algo: PPO\n  timesteps: 640\n  n_envs: 4\n  seed: 3\n"
        + f"  hyperparams: {{n_steps: {N_STEPS}, batch_size: 64, n_epochs: 2, learning_rate: lin_0.0003,"
        + " policy_kwargs: {net_arch: [32, 32]}}\n"
    )
    return path


def test_an_env_runner_killed_with_sigkill_comes_back_and_training_goes_on(
    ray_cluster: Any, tmp_path: Path
) -> None:
    seen: list[dict[str, Any]] = []

    def on_iteration(algo: Any, result: dict[str, Any]) -> None:
        group = algo.env_runner_group
        pids = group.foreach_env_runner(lambda runner: os.getpid(), local_env_runner=False)
        sizes = group.foreach_env_runner(lambda runner: runner.env.num_envs, local_env_runner=False)
        steps = int(result["env_runners"]["num_env_steps_sampled_lifetime"])
        seen.append({"pids": list(pids), "sizes": list(sizes), "steps": steps})
        if len(seen) == 1:
            os.kill(pids[0], signal.SIGKILL)

    run_dir = tmp_path / "run"
    result = train_rllib(experiment(tmp_path), run_dir=run_dir, runners=1, on_iteration=on_iteration)
    killed = seen[0]["pids"][0]
    assert result.timesteps >= 640, "training stopped before its timesteps"
    later = [s for s in seen[1:] if s["pids"]]
    assert later and all(killed not in s["pids"] for s in later), f"no new runner after the kill: {seen}"
    assert all(s["sizes"] == [K] for s in seen if s["sizes"]), "a runner hosts a batch env of K instances"
    steps = [s["steps"] for s in seen]
    assert steps == sorted(steps) and steps[-1] > steps[0]
    assert (run_dir / "checkpoint").is_dir()
    assert (run_dir / "checkpoints" / f"iter_{result.iterations}").is_dir()
