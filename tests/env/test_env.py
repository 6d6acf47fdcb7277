"""FmuEnv: Gymnasium/SB3 checkers, agreement with FMPy's simulate_fmu, seeding, semantics."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from fmpy import simulate_fmu
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from bridge.env.fmu_env import FmuEnv, make
from bridge.errors import BridgeError
from bridge.experiment.config import parse_experiment
from bridge.experiment.examples import GYM_IDS, example_experiment, example_names


def run(
    env: FmuEnv, actions: Any, seed: int | None = 0, options: dict[str, Any] | None = None
) -> dict[str, Any]:
    obs, info = env.reset(seed=seed, options=options)
    observations, rewards, outputs = [obs], [], [info["outputs"]]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        outputs.append(info["outputs"])
        if terminated or truncated:
            break
    return {
        "obs": np.array(observations),
        "rewards": np.array(rewards),
        "outputs": np.array(outputs),
        "info": info,
        "scenario": info.get("scenario"),
    }


@pytest.mark.parametrize("name", example_names())
def test_examples_pass_both_env_checkers(name: str) -> None:
    with FmuEnv(example_experiment(name)) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded observation spaces are deliberate
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)


def _heater_experiment(fmu: Path) -> dict[str, Any]:
    return {
        "model": {
            "fmu": str(fmu),
            "step_size": 1.0,
            "episode_duration": 30.0,
            "parameters": {"label": "lab"},
        },
        "actions": {"inputs": ["power"], "low": {"power": 0.0}, "high": {"power": 200.0}},
        "observations": {"outputs": ["room", "steps", "heating"], "references": ["room_ref"]},
        "reward": {"terms": [{"tracking": {"output": "room", "reference": "room_ref", "norm": "squared"}}]},
        "scenarios": {"warm": {"references": {"room_ref": 22.0}, "inputs": {"mode": 3}}},
        "randomization": {"parameters": {"ambient": {"uniform": [5.0, 15.0]}}},
    }


@pytest.mark.integration  # Python-backed FMUs run in a child process by default
@pytest.mark.parametrize("fixture", ["pythonfmu_heater2", "pythonfmu_heater3"])
def test_fmus_from_other_exporters_pass_both_env_checkers(
    fixture: str, request: pytest.FixtureRequest
) -> None:
    experiment = parse_experiment(_heater_experiment(request.getfixturevalue(fixture)))
    with FmuEnv(experiment) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)
        result = run(env, [np.array([1.0], dtype=np.float32)] * 5)
        assert result["outputs"][-1][1] == 5  # the integer step counter, read as an integer


def test_dymola_fmu_passes_both_env_checkers(eta_ctrl_fmus: dict[str, Path]) -> None:
    experiment = parse_experiment(
        {
            "model": {
                "fmu": str(eta_ctrl_fmus["damped_oscillator"]),
                "step_size": 0.01,
                "episode_duration": 2.0,
            },
            "actions": {"inputs": ["f"], "low": {"f": -5.0}, "high": {"f": 5.0}},
            "observations": {"outputs": ["s", "v"]},
            "reward": {"expression": "-abs(s - 0.1)"},
        }
    )
    with FmuEnv(experiment) as env, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=False)


def test_scenario_trajectory_equals_fmpy_simulate_fmu() -> None:
    """Action 0.5 -> 12 V held, a load step from the scenario, fixed parameters, two FMU steps per
    sample: the env's outputs at every sample equal FMPy's own co-simulation within 1e-9."""
    experiment = parse_experiment(
        {
            "model": {
                "fmu": "example:dcmotor",
                "step_size": 0.005,
                "sampling_time": 0.01,
                "episode_duration": 2.0,
                "parameters": {"J": 0.012, "R": 1.1},
            },
            "actions": {"inputs": ["voltage"]},
            "observations": {"outputs": ["omega", "current"]},
            "reward": {"terms": [{"alive": 1.0}]},
            "scenarios": {"load": {"inputs": {"load_torque": {"step": {"time": 1.0075, "after": 0.3}}}}},
        }
    )
    with FmuEnv(experiment) as env:
        result = run(env, [np.array([0.5], dtype=np.float32)] * 200)
        fmu = str(env.plant.fmu_path)
    # Scenario inputs are held per agent sample, like actions. FMPy sets inputs at each of its
    # communication points (every 5 ms) from this table: 0 N.m up to 1.005 s, 0.3 N.m from 1.01 s,
    # which is what the env's step at 1.0075 s gives (no duplicate times: no FMPy input event).
    t = np.array([0.0, 1.005, 1.01, 2.0])
    signal = np.array(
        list(zip(t, [12.0] * 4, [0.0, 0.0, 0.3, 0.3])),
        dtype=[("time", np.float64), ("voltage", np.float64), ("load_torque", np.float64)],
    )
    ref = simulate_fmu(
        fmu,
        fmi_type="CoSimulation",
        start_values={"J": 0.012, "R": 1.1},
        input=signal,
        stop_time=2.0,
        step_size=0.005,
        output_interval=0.01,
        output=["omega", "current"],
    )
    samples = np.arange(201) * 0.01
    rows = [int(np.flatnonzero(np.abs(ref["time"] - t) < 1e-9)[-1]) for t in samples]  # skip event rows
    expected = np.column_stack([ref["omega"][rows], ref["current"][rows]])
    assert len(result["outputs"]) == 201
    np.testing.assert_allclose(result["outputs"], expected, rtol=0, atol=1e-9)
    assert result["outputs"][150, 0] < result["outputs"][100, 0] + 10  # the load step is felt


def test_same_seed_same_episode_different_seed_differs() -> None:
    path = example_experiment("cartpole_continuous")  # uncertain parameters and sensor noise
    actions = [np.array([0.1], dtype=np.float32)] * 30
    with FmuEnv(path) as a, FmuEnv(path) as b:
        first, second = run(a, actions, seed=7), run(b, actions, seed=7)
        np.testing.assert_array_equal(first["obs"], second["obs"])
        np.testing.assert_array_equal(first["rewards"], second["rewards"])
        _, info_a = a.reset(seed=7)
        _, info_b = b.reset(seed=8)
        assert info_a["drawn"] != info_b["drawn"]
        other = run(b, actions, seed=8)
        assert not np.array_equal(first["obs"][:5], other["obs"][:5])


def test_reset_with_same_seed_replays_including_scenario_choice() -> None:
    with FmuEnv(example_experiment("dcmotor_tracking")) as env:
        actions = [np.array([0.3], dtype=np.float32)] * 20
        episodes = [run(env, actions, seed=3) for _ in range(2)]
        assert episodes[0]["scenario"] == episodes[1]["scenario"]
        np.testing.assert_array_equal(episodes[0]["obs"], episodes[1]["obs"])


def test_sensor_noise_changes_observation_not_outputs() -> None:
    base = parse_experiment(
        {
            "model": {"fmu": "example:cartpole", "step_size": 0.02, "episode_duration": 1.0},
            "actions": {"inputs": ["force"], "low": {"force": -10}, "high": {"force": 10}},
            "observations": {"outputs": ["x", "theta"], "scale": "none"},
            "reward": {"terms": [{"alive": 1.0}]},
            "noise": {"observations": {"theta": {"normal": [0.0, 0.01]}}},
        }
    )
    with FmuEnv(base) as env:
        result = run(env, [np.zeros(1, dtype=np.float32)] * 10)
    theta_obs, theta_true = result["obs"][:, 1], result["outputs"][:, 1]
    assert np.all(result["obs"][:, 0] == result["outputs"][:, 0].astype(np.float32))
    noise = theta_obs - theta_true
    assert 0.001 < np.std(noise) < 0.05


def test_termination_and_truncation_are_distinct() -> None:
    with FmuEnv(example_experiment("cartpole_balance")) as env:
        env.reset(seed=0)
        terminated = truncated = False
        while not (terminated or truncated):
            _, _reward, terminated, truncated, info = env.step(1)  # always push right: the pole falls
        assert terminated and not truncated and info["reason"].startswith("bounds:")
        with pytest.raises(BridgeError, match="reset"):
            env.step(1)
    short = parse_experiment(
        {
            "model": {"fmu": "example:cartpole", "step_size": 0.02, "episode_duration": 0.1},
            "actions": {"inputs": ["force"], "type": "discrete", "levels": {"force": [-10, 10]}},
            "observations": {"outputs": ["theta"]},
            "reward": {"terms": [{"alive": 1.0}], "termination_penalty": -100.0},
            "termination": {"bounds": {"theta": [-1.0, 1.0]}},
        }
    )
    with FmuEnv(short) as env:
        result = run(env, [0, 1, 0, 1, 0, 1, 0])
        assert len(result["rewards"]) == 5 and result["info"]["reason"] == "time"
        assert result["rewards"].sum() == 5.0  # no penalty on truncation


def test_fmu_requested_termination_ends_the_episode() -> None:
    experiment = parse_experiment(
        {
            "model": {
                "fmu": "example:cartpole",
                "step_size": 0.02,
                "episode_duration": 5.0,
                "parameters": {"track_limit": 0.05},
            },
            "actions": {"inputs": ["force"], "type": "discrete", "levels": {"force": [-10, 10]}},
            "observations": {"outputs": ["x"]},
            "reward": {"terms": [{"alive": 1.0}], "termination_penalty": -5.0},
        }
    )
    with FmuEnv(experiment) as env:
        result = run(env, [1] * 100)
    assert result["info"]["reason"] == "fmu" and result["rewards"][-1] == -4.0


def test_discrete_and_multidiscrete_actions_map_to_levels() -> None:
    experiment = parse_experiment(
        {
            "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 1.0},
            "actions": {
                "inputs": ["voltage", "load_torque"],
                "type": "multi_discrete",
                "levels": {"voltage": [-12, 0, 12], "load_torque": [0.0, 0.2]},
            },
            "observations": {"outputs": ["omega"]},
            "reward": {"terms": [{"effort": {"name": "voltage", "norm": "abs", "weight": 1.0}}]},
        }
    )
    with FmuEnv(experiment) as env:
        assert env.action_space == gym.spaces.MultiDiscrete([3, 2])
        env.reset(seed=0)
        _, reward, *_ = env.step(np.array([2, 1]))
        assert reward == -12.0
        with pytest.raises(BridgeError, match="invalid action"):
            env.step(np.array([3, 0]))


def test_nan_action_is_a_clear_error() -> None:
    with FmuEnv(example_experiment("cartpole_continuous")) as env:
        env.reset(seed=0)
        with pytest.raises(BridgeError, match=r"invalid action .*nan.*diverged"):
            env.step(np.array([np.nan], dtype=np.float32))


def test_reward_terms_expression_and_callable_add_up() -> None:
    experiment = parse_experiment(
        {
            "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 0.5},
            "actions": {"inputs": ["voltage"]},
            "observations": {"outputs": ["omega"], "references": ["omega_ref"]},
            "reward": {
                "terms": [
                    {"alive": 2.0},
                    {
                        "tracking": {
                            "output": "omega",
                            "reference": "omega_ref",
                            "norm": "squared",
                            "scale": 10.0,
                        }
                    },
                    {"rate": {"name": "voltage", "norm": "abs", "weight": 0.5}},
                ],
                "expression": "0.01 * current - abs(omega_ref - omega) / 100",
                "callable": "rewards_for_tests:half_current",
            },
            "scenarios": {"s": {"references": {"omega_ref": 50.0}}},
        }
    )
    with FmuEnv(experiment) as env:
        env.reset(seed=0)
        _, _, _, _, _info0 = env.step(np.array([0.25], dtype=np.float32))
        _, reward, _, _, info = env.step(np.array([0.5], dtype=np.float32))
        omega, current = info["outputs"][0], info["outputs"][1]
        expected = (
            2.0
            - ((omega - 50.0) / 10.0) ** 2
            - 0.5 * abs(12.0 - 6.0)
            + 0.01 * current
            - abs(50.0 - omega) / 100
            + 0.5 * current
        )
        assert reward == pytest.approx(expected, rel=1e-12)


def test_observation_history_stacks_the_last_k_samples() -> None:
    experiment = parse_experiment(
        {
            "model": {
                "fmu": "example:cartpole",
                "step_size": 0.02,
                "episode_duration": 1.0,
                "parameters": {"theta0": 0.05},
            },
            "actions": {"inputs": ["force"], "low": {"force": -10}, "high": {"force": 10}},
            "observations": {"outputs": ["theta"], "scale": "none", "history": 3},
            "reward": {"terms": [{"alive": 1.0}]},
        }
    )
    with FmuEnv(experiment) as env:
        result = run(env, [np.zeros(1, dtype=np.float32)] * 4)
    theta = result["outputs"][:, 0].astype(np.float32)
    np.testing.assert_array_equal(result["obs"][0], [theta[0]] * 3)
    np.testing.assert_array_equal(result["obs"][4], theta[2:5])


def test_episode_and_state_hooks(tmp_path: Path) -> None:
    experiment = parse_experiment(
        {
            "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 0.2},
            "actions": {"inputs": ["voltage"]},
            "observations": {"outputs": ["omega"]},
            "reward": {"terms": [{"alive": 1.0}]},
            "hooks": {
                "episode": "rewards_for_tests:heavier_rotor",
                "state": "rewards_for_tests:load_after_5",
            },
        }
    )
    with FmuEnv(experiment) as env:
        env.reset(seed=0)
        assert env.task.episode is not None and env.task.episode.values["J"] == 0.05
        for _ in range(10):
            _, _, _, _, _info = env.step(np.zeros(1, dtype=np.float32))
        assert env.plant.model.get(["load_torque"])["load_torque"] == 0.25


def test_render_modes() -> None:
    with FmuEnv(example_experiment("cartpole_balance"), render_mode="rgb_array") as env:
        env.reset(seed=0)
        env.step(0)
        frame = env.render()
        assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    with FmuEnv(example_experiment("dcmotor_tracking"), render_mode="ansi") as env:
        env.reset(seed=0)
        env.step(np.zeros(1, dtype=np.float32))
        assert "omega=" in env.render()


@pytest.mark.parametrize("env_id", sorted(GYM_IDS))
def test_gymnasium_ids_make_working_envs(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_versions_are_distinct_and_immutable() -> None:
    with make("cartpole_balance") as v0, FmuEnv(example_experiment("cartpole_balance"), version="v1") as v1:
        assert v0.experiment.version == "v0" and v1.experiment.version == "v1"
        r0, r1 = run(v0, [1] * 200), run(v1, [1] * 200)
        assert r0["rewards"][-1] == 1.0 and r1["rewards"][-1] < -9.0  # v1's termination penalty


@pytest.mark.integration
def test_subproc_vec_env_opens_the_fmu_in_each_worker() -> None:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    path = str(example_experiment("cartpole_balance"))
    vec = make_vec_env(FmuEnv, n_envs=2, seed=0, vec_env_cls=SubprocVecEnv, env_kwargs={"experiment": path})
    try:
        obs = vec.reset()
        assert obs.shape == (2, 4)
        ended = 0
        for _ in range(100):  # constant pushes: every episode falls within ~20 samples
            obs, _rewards, dones, infos = vec.step(np.array([0, 1]))
            for done, info in zip(dones, infos):
                if done:
                    ended += 1
                    assert info["terminal_observation"].shape == (4,)  # SB3's auto-reset contract
        assert ended >= 4 and np.isfinite(obs).all()
    finally:
        vec.close()


def test_non_finite_fmu_output_is_a_clear_error_not_a_nan_observation() -> None:
    with FmuEnv(example_experiment("cartpole_balance")) as env:
        env.reset(seed=0)
        with pytest.raises(
            BridgeError, match=r"non-finite outputs theta=nan at sample 3: the model diverged"
        ):
            env.task.step_result([0.0, 0.0, float("nan"), 0.0], 3, False, env.np_random)


def test_nan_signal_counts_as_outside_its_bounds() -> None:
    with FmuEnv(example_experiment("cartpole_balance")) as env:
        signals = [0.0, 0.0, float("nan"), 0.0, 10.0]
        assert env.task.termination_reason(signals) == "bounds:theta"
        assert env.task.termination_reason([0.0, 0.0, 0.1, 0.0, 10.0]) is None
        assert env.task.termination_reason([-3.0, 0.0, 0.1, 0.0, 10.0]) == "bounds:x"
