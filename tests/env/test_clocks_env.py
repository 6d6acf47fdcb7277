"""FMUs whose clocks tick, as Gymnasium envs: scheduled execution and co-simulation in event mode."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from bridge.env.batch import BatchEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.models.clocked import clocks_fmu


def _experiment(interface: str, **model: Any) -> dict[str, Any]:
    return {
        "model": {"fmu": str(clocks_fmu(interface)), "step_size": 0.25, "episode_duration": 3.0, **model},
        "actions": {"inputs": ["r"], "low": {"r": -1.0}, "high": {"r": 1.0}},
        "observations": {"outputs": ["x", "u", "t_ctrl", "n_trigger", "t_trigger"]},
        "reward": {"expression": "-abs(x - 0.5)"},
    }


def test_a_scheduled_execution_only_fmu_runs_as_an_env_and_passes_both_checkers() -> None:
    experiment = parse_experiment(_experiment("se"))
    with FmuEnv(experiment) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded observation spaces are deliberate
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)
        env.reset(seed=0)
        for j in range(1, 13):
            obs, _, terminated, truncated, _ = env.step(np.array([0.5], dtype=np.float32))
            # the controller's partition ran at each 0.1 s tick up to the agent's sample time
            assert obs[2] == pytest.approx(np.floor(0.25 * j / 0.1 + 1e-9) * 0.1, abs=1e-6)
        assert truncated and not terminated


def test_a_clock_schedule_from_the_experiment_ticks_in_every_episode() -> None:
    experiment = parse_experiment(_experiment("cs", clock_schedule={"trigger": [0.5, 1.1, 2.9]}))
    with FmuEnv(experiment) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)
        for _ in range(2):
            env.reset(seed=1)
            counts = [env.step(np.array([0.0], dtype=np.float32))[0][3] for _ in range(12)]
            # at 0.25 s per sample: the ticks at 0.5, 1.1 and 2.9 s are seen after samples 2, 5 and 12
            assert counts == [0, 1, 1, 1, 2, 2, 2, 2, 2, 2, 2, 3]


@pytest.mark.parametrize("interface", ["cs", "me", "se"])
def test_the_agent_ticks_a_triggered_clock_with_an_action(interface: str) -> None:
    """actions.inputs may name a triggered input clock: [0, 1] by default, ticked above 0.5, at the
    start of the sample (the time the agent acted)."""
    experiment = _experiment(interface)
    experiment["actions"]["inputs"] = ["r", "trigger"]
    with FmuEnv(parse_experiment(experiment)) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)
        env.reset(seed=0)
        ticked = (1, 4, 5)
        seen = []
        for j in range(8):
            action = np.array([0.0, 1.0 if j in ticked else -1.0], dtype=np.float32)
            obs = env.step(action)[0]
            seen.append((obs[3], obs[4]))
        counts = [c for c, _ in seen]
        assert counts == [0, 1, 1, 1, 2, 3, 3, 3]
        assert seen[-1][1] == pytest.approx(0.25 * ticked[-1])  # t_trigger: the last tick's time


@pytest.mark.parametrize("interface", ["cs", "se"])
def test_a_batch_of_clocked_fmus_equals_single_envs(interface: str) -> None:
    """The batch steps clocked FMUs in Python (no native loop) and gives what FmuEnv gives."""
    experiment = _experiment(interface)
    experiment["actions"]["inputs"] = ["r", "trigger"]
    exp = parse_experiment(experiment)
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.0, 1.0, size=(10, 2, 2)).astype(np.float32)
    batch = BatchEnv(exp, 2)
    try:
        batch.reset_all([0, 1])
        batched = [batch.step(a)[0].copy() for a in actions]
    finally:
        batch.close()
    for i in range(2):
        with FmuEnv(exp) as env:
            env.reset(seed=i)
            single = [env.step(a[i])[0] for a in actions]
        np.testing.assert_array_equal(np.array(batched)[:, i], np.array(single))


def test_clock_settings_the_fmu_cannot_take_are_refused_when_the_env_opens() -> None:
    bad = _experiment("cs", clock_schedule={"c_const": [0.5]})
    with pytest.raises(ConfigError, match=r"clock_schedule names 'c_const'.*\['trigger'\]"):
        FmuEnv(parse_experiment(bad))
    no_clocks = _experiment("cs", clock_intervals={"c_fixed": 0.2})
    no_clocks["model"]["fmu"] = "example:feedthrough:3.0"
    no_clocks["actions"] = {"inputs": ["u"], "low": {"u": -1.0}, "high": {"u": 1.0}}
    no_clocks["observations"] = {"outputs": ["y"]}
    no_clocks["reward"] = {"expression": "-abs(y)"}
    with pytest.raises(ConfigError, match=r"clock_intervals and clock_schedule need FMI 3.0 input clocks"):
        FmuEnv(parse_experiment(no_clocks))
