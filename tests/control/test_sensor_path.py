"""One sensor path for every controller: a baseline reads what the agent's sensors report.

The experiment adds sensor noise to the observed motor speed. A scripted policy keeps the signals
it is handed; they must equal the exact model values plus the noise the agent's observation got,
on the single-env path and the batch path alike, and the exact values under
``evaluation.baseline_signals: exact``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rewards_for_tests import SeenSignals

from agents.evaluate import evaluate, run_episode
from agents.policies import make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment

NOISE_STD = 0.5


def _experiment(tmp_path: Path, **evaluation: Any) -> Path:
    data = {
        "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 0.3},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega", "current"], "references": ["omega_ref"], "scale": "none"},
        "reward": {"terms": [{"tracking": {"output": "omega", "reference": "omega_ref", "norm": "abs"}}]},
        "scenarios": {"hold": {"references": {"omega_ref": 10.0}}},
        "noise": {"observations": {"omega": {"normal": [0.0, NOISE_STD]}}},
        "evaluation": {"metrics": {"tracking": [["omega", "omega_ref"]]}, **evaluation},
    }
    path = tmp_path / "noisy_motor.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _episode(path: Path, seed: int) -> tuple[list[dict[str, float]], np.ndarray, np.ndarray, list[str]]:
    """Signals the policy saw, the exact signal rows, the episode's sensor noise, and the names."""
    SeenSignals.calls.clear()
    env = FmuEnv(load_experiment(path))
    try:
        trace = run_episode(env, make_policy("python:rewards_for_tests:record_signals", {}), seed, "hold")
        noise = env.unwrapped.task.episode_tables().observation_noise
        names = list(env.unwrapped.task.signal_names)
    finally:
        env.close()
    exact = np.column_stack([trace.signals[name] for name in names])
    return list(SeenSignals.calls), exact, noise, names


def test_a_baseline_reads_the_noisy_sensor_the_agent_reads(tmp_path: Path) -> None:
    seen, exact, noise, names = _episode(_experiment(tmp_path), seed=3)
    omega, current = names.index("omega"), names.index("current")
    assert len(seen) == len(exact) - 1  # one call per sample, before each step
    measured = np.array([[s[name] for name in names] for s in seen])
    np.testing.assert_array_equal(measured[:, omega], exact[:-1, omega] + noise[: len(seen), 0])
    np.testing.assert_array_equal(measured[:, current], exact[:-1, current])  # no noise declared on it
    assert np.std(measured[:, omega] - exact[:-1, omega]) > NOISE_STD / 3  # the noise is really there


def test_the_observation_and_the_baseline_see_the_same_noise(tmp_path: Path) -> None:
    path = _experiment(tmp_path)
    env = FmuEnv(load_experiment(path))
    try:
        obs, _ = env.reset(seed=5, options={"scenario": "hold"})
        task = env.unwrapped.task
        for _ in range(5):
            assert obs[0] == np.float32(task.controller_signals()["omega"])  # scale: none
            obs, *_ = env.step(np.array([0.3], dtype=np.float32))
    finally:
        env.close()


def test_exact_signals_when_the_experiment_says_so(tmp_path: Path) -> None:
    seen, exact, _, names = _episode(_experiment(tmp_path, baseline_signals="exact"), seed=3)
    measured = np.array([[s[name] for name in names] for s in seen])
    np.testing.assert_array_equal(measured, exact[:-1])


@pytest.mark.parametrize("signals", ["measured", "exact"])
def test_the_batch_path_hands_baselines_the_same_signals(tmp_path: Path, signals: str) -> None:
    path = _experiment(tmp_path, baseline_signals=signals)
    SeenSignals.calls.clear()
    evaluate(["python:rewards_for_tests:record_signals"], path, episodes=2, seed=7, batch=False)
    single = list(SeenSignals.calls)
    SeenSignals.calls.clear()
    evaluate(["python:rewards_for_tests:record_signals"], path, episodes=2, seed=7, batch=True)
    batch = list(SeenSignals.calls)
    assert len(single) == len(batch) > 0
    # the batch interleaves its two episodes; compare the multisets of what each call saw
    key = sorted(tuple(sorted(s.items())) for s in single)
    assert key == sorted(tuple(sorted(s.items())) for s in batch)
