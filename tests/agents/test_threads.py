"""torch's thread count follows the network's size: one thread for an RL policy of SB3's size
(torch's pool would spin against the envs), more only for a large network; OMP_NUM_THREADS wins."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from agents.threads import LARGE_NETWORK_PARAMS, threads_for, use_threads_for
from agents.train import train
from bridge.experiment.examples import example_experiment


def test_small_networks_get_one_thread_and_large_ones_up_to_four_usable_cores() -> None:
    assert threads_for(10_000, cpus=16) == 1
    assert threads_for(LARGE_NETWORK_PARAMS, cpus=2) == 2
    assert threads_for(50 * LARGE_NETWORK_PARAMS, cpus=16) == 4
    assert threads_for(50 * LARGE_NETWORK_PARAMS, cpus=1) == 1


def test_train_sets_one_thread_for_its_small_policy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)  # tests/conftest.py sets it: not the user's
    torch.set_num_threads(2)  # torch's default on a 2-core machine
    try:
        overrides = {"timesteps": 64, "n_envs": 1, "eval_every": 100_000, "hyperparams": {"n_steps": 64}}
        train(
            example_experiment("cartpole_balance"),
            overrides=overrides,
            run_dir=tmp_path / "run",
            progress=False,
        )
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(1)  # the test session's count (tests/conftest.py)


def test_omp_num_threads_is_the_users_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    torch.set_num_threads(2)
    try:
        assert use_threads_for(torch.nn.Linear(4, 4)) == 2 and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)
