"""The slow plant (``models/slow_plant``: doStep and initialisation take a set wall-clock time)
in this process and in an isolated child: it works, and no deadline the user did not set ends it."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from bridge.env import FmuEnv
from bridge.experiment.config import load_experiment
from tests.slow_plant import slow_experiment

ACTION = np.array([0.5], dtype=np.float32)


def run_episode(env: FmuEnv, seed: int) -> tuple[list[float], float]:
    """The observed x over one episode (its reset state first), and the time its steps took."""
    obs, _ = env.reset(seed=seed)
    xs, start, done = [float(obs[0])], time.perf_counter(), False
    while not done:
        obs, _, terminated, truncated, _ = env.step(ACTION)
        xs.append(float(obs[0]))
        done = terminated or truncated
    return xs, time.perf_counter() - start


def lag(x0: float, u: float, samples: int, tau_s: float = 0.5, h_s: float = 0.1) -> list[float]:
    """The first-order lag's exact samples (RK4 with 0.01 s substeps agrees to ~1e-9)."""
    return [u + (x0 - u) * float(np.exp(-k * h_s / tau_s)) for k in range(samples + 1)]


def test_slow_plant_in_process_steps_as_slowly_as_it_says_and_follows_its_equation(tmp_path: Path) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.1, init_delay_s=0.3, duration_s=0.3)
    with FmuEnv(load_experiment(path)) as env:
        xs, took_s = run_episode(env, seed=1)
    assert len(xs) == 4
    assert took_s >= 3 * 0.1, f"3 steps of 0.1 s each took {took_s:.3f} s: the delay is not in doStep"
    np.testing.assert_allclose(xs, lag(xs[0], 0.5, 3), rtol=0, atol=1e-6)


@pytest.mark.integration  # child processes
def test_isolated_slow_plant_initialising_longer_than_its_step_deadline_works(tmp_path: Path) -> None:
    """Initialisation (the first reset, and every reset after it: the random x0 initialises again)
    takes 2 s, longer than the 1 s step deadline set in the file: the start and the first reset
    wait as long as the child lives, later resets get four times the measured first one."""
    path = slow_experiment(
        tmp_path,
        step_delay_s=0.05,
        init_delay_s=2.0,
        duration_s=0.2,
        model_extra="isolation: {timeout: 1.0}",
    )
    with FmuEnv(load_experiment(path)) as env:
        assert env.plant.isolated
        first, _ = run_episode(env, seed=1)
        second, _ = run_episode(env, seed=2)
    np.testing.assert_allclose(first, lag(first[0], 0.5, 2), rtol=0, atol=1e-6)
    np.testing.assert_allclose(second, lag(second[0], 0.5, 2), rtol=0, atol=1e-6)
    assert first[0] != second[0], "the second episode drew its own initial state"


@pytest.mark.parametrize("where", ["in-process", pytest.param("isolated", marks=pytest.mark.integration)])
def test_slow_plant_vector_env_over_two_slow_plants(tmp_path: Path, where: str) -> None:
    """Gymnasium's SyncVectorEnv over two slow FmuEnvs (in process or isolated)."""
    import gymnasium as gym

    extra = "isolation: {timeout: 5.0}" if where == "isolated" else ""
    exp = load_experiment(slow_experiment(tmp_path, step_delay_s=0.1, duration_s=0.2, model_extra=extra))
    vec = gym.vector.SyncVectorEnv([lambda: FmuEnv(exp) for _ in range(2)])
    try:
        obs, _ = vec.reset(seed=[1, 2])
        x0 = obs[:, 0].copy()
        for _ in range(2):
            obs, _, _, _, _ = vec.step(np.full((2, 1), 0.5, dtype=np.float32))
        expected = [lag(float(x), 0.5, 2)[-1] for x in x0]
        np.testing.assert_allclose(obs[:, 0], expected, rtol=0, atol=1e-6)
    finally:
        vec.close()


def test_batch_env_over_slow_plants_follows_their_equation(tmp_path: Path) -> None:
    from bridge.env.batch import BatchVectorEnv

    exp = load_experiment(slow_experiment(tmp_path, step_delay_s=0.1, init_delay_s=0.2, duration_s=0.3))
    env = BatchVectorEnv(exp, 2)  # 3 samples an episode: 2 steps stay inside the first
    try:
        obs, _ = env.reset(seed=3)
        x0 = obs[:, 0].copy()
        for _ in range(2):
            obs, _, _, _, _ = env.step(np.full((2, 1), 0.5, dtype=np.float32))
        expected = [lag(float(x), 0.5, 2)[-1] for x in x0]
        np.testing.assert_allclose(obs[:, 0], expected, rtol=0, atol=1e-6)
    finally:
        env.close()
