"""The batch env against independent references: gymnasium's SyncVectorEnv and SB3's DummyVecEnv
over N single FmuEnv (bit for bit), per-env error isolation, and the SB3 interface in training."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from bridge.env.batch import BatchVecEnv, BatchVectorEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import StepError
from bridge.experiment.config import Experiment, load_experiment
from bridge.experiment.examples import example_experiment

N = 5
# Everything the Task can do per step: continuous actions with actuator noise, history, clipping,
# errors, the last action, sensor noise, a squared term and a reward expression, a penalty.
RICH = """\
model: {fmu: 'example:cartpole', step_size: 0.01, sampling_time: 0.02, episode_duration: 1.0}
actions: {inputs: [force], type: continuous}
observations:
  outputs: [x, theta, theta_dot]
  history: 3
  clip: 4.0
  include_action: true
reward:
  terms:
    - alive: 1.0
    - signal: {name: theta, norm: squared, weight: 0.5, scale: 0.2}
    - signal: {name: x, norm: abs, weight: 0.1, scale: 2.4}
  expression: "-0.01 * abs(theta_dot) + (0.5 if abs(x) < 0.1 else 0.0) - sqrt(x**2 + 1e-3)"
  termination_penalty: -5.0
termination: {bounds: {x: [-2.4, 2.4], theta: [-0.3, 0.3]}}
randomization:
  parameters: {theta0: {uniform: [-0.1, 0.1]}, x0: {normal: [0.0, 0.05]}}
noise:
  observations: {theta: {normal: [0.0, 0.01]}}
  actions: {force: {uniform: [-0.5, 0.5]}}
"""
TYPED = """\
model: {fmu: 'example:typed', step_size: 0.1, episode_duration: 2.0}
actions: {inputs: [real_in], low: {real_in: -1}, high: {real_in: 1}}
observations: {outputs: [real_out, real_integral]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {}
  breaks: {parameters: {fail_at_step: 3}}
schedule: {mode: fixed}
"""


def experiment_of(
    name: str, tmp_path: Path, text: str | None = None, version: str | None = None
) -> Experiment:
    if text is None:
        return load_experiment(example_experiment(name), version=version)
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return load_experiment(path)


# The same in model exchange (the native batch loop over fixed-step integrators), with a track end
# at which the FMU asks to terminate from its event iteration.
RICH_ME = RICH.replace(
    "model: {fmu: 'example:cartpole',",
    "model: {fmu: 'example:cartpole', interface: me, solver: rk4, solver_substeps: 4,\n"
    "        parameters: {track_limit: 0.3},",
)
CASES = [
    ("dcmotor_tracking", None, None),
    ("cartpole_balance", None, "v1"),
    ("cartpole_continuous", None, None),
    ("rich", RICH, None),
    ("rich_me", RICH_ME, None),
]


def actions(space: gym.Space[Any], rng: np.random.Generator, n: int = N) -> np.ndarray:
    if isinstance(space, gym.spaces.Discrete):
        return rng.integers(0, int(space.n), size=n)
    return rng.uniform(-1.3, 1.3, size=(n, *space.shape)).astype(np.float32)


# a batch of one steps through the scalar Task (its own path): checked as the others
WAYS = [(True, N), (False, N), (True, 1)]
WAY_IDS = ["native", "python", "one-env"]


@pytest.mark.parametrize("way", WAYS, ids=WAY_IDS)
@pytest.mark.parametrize(("name", "text", "version"), CASES, ids=[c[0] for c in CASES])
def test_batch_vector_env_equals_sync_vector_env_over_fmu_envs_bit_for_bit(
    tmp_path: Path, name: str, text: str | None, version: str | None, way: tuple[bool, int]
) -> None:
    native, n = way
    exp = experiment_of(name, tmp_path, text, version)
    batch = BatchVectorEnv(exp, n, native=native)
    reference = SyncVectorEnv([lambda: FmuEnv(exp) for _ in range(n)], autoreset_mode=AutoresetMode.SAME_STEP)
    assert batch.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert batch.observation_space == reference.observation_space
    obs, info = batch.reset(seed=7)
    ref_obs, ref_info = reference.reset(seed=7)
    np.testing.assert_array_equal(obs, ref_obs)
    assert list(info["scenario"]) == list(ref_info["scenario"])
    rng = np.random.default_rng(1)
    ends = 0
    for _ in range(310):
        a = actions(batch.single_action_space, rng, n)
        obs, reward, terminated, truncated, info = batch.step(a)
        r_obs, r_reward, r_terminated, r_truncated, r_info = reference.step(a)
        np.testing.assert_array_equal(obs, r_obs)
        np.testing.assert_array_equal(reward, r_reward)
        np.testing.assert_array_equal(terminated, r_terminated)
        np.testing.assert_array_equal(truncated, r_truncated)
        assert batch.observation_space.contains(obs)
        if "final_obs" in r_info:
            ends += int(r_info["_final_obs"].sum())
            np.testing.assert_array_equal(info["_final_obs"], r_info["_final_obs"])
            for i in np.flatnonzero(r_info["_final_obs"]):
                np.testing.assert_array_equal(info["final_obs"][i], r_info["final_obs"][i])
                assert info["final_info"]["reason"][i] == r_info["final_info"]["reason"][i]
    assert ends > 0, "no episode ended: the test would not cover autoreset"
    batch.close()
    reference.close()


def test_batch_vec_env_equals_sb3_dummy_vec_env_bit_for_bit() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

    exp = load_experiment(example_experiment("dcmotor_tracking"))
    batch = BatchVecEnv(exp, N)
    reference = DummyVecEnv([lambda: FmuEnv(exp) for _ in range(N)])
    assert isinstance(batch, VecEnv)
    batch.seed(3)
    reference.seed(3)
    np.testing.assert_array_equal(batch.reset(), reference.reset())
    rng = np.random.default_rng(2)
    dones_seen = 0
    for _ in range(320):
        a = rng.uniform(-1, 1, size=(N, 1)).astype(np.float32)
        obs, reward, dones, infos = batch.step(a)
        r_obs, r_reward, r_dones, r_infos = reference.step(a)
        np.testing.assert_array_equal(obs, r_obs)
        np.testing.assert_array_equal(reward, r_reward)
        np.testing.assert_array_equal(dones, r_dones)
        for i in np.flatnonzero(r_dones):
            dones_seen += 1
            np.testing.assert_array_equal(
                infos[i]["terminal_observation"], r_infos[i]["terminal_observation"]
            )
            assert infos[i]["TimeLimit.truncated"] == r_infos[i]["TimeLimit.truncated"]
    assert dones_seen == N  # 300-sample episodes: every env truncated once
    batch.close()
    reference.close()


@pytest.mark.parametrize("native", [True, False], ids=["native", "python"])
def test_a_failing_env_is_truncated_and_reset_while_the_others_go_on(tmp_path: Path, native: bool) -> None:
    exp = experiment_of("typed", tmp_path, TYPED)
    env = BatchVectorEnv(exp, 3, native=native)
    env.reset(seed=0, options={"scenario": ["fine", "breaks", "fine"]})
    zero = np.zeros((3, 1), dtype=np.float32)
    for _ in range(2):
        _, _, terminated, truncated, info = env.step(zero)
        assert not (terminated | truncated).any()
    _, reward, terminated, truncated, info = env.step(zero)  # doStep 3 of env 1 fails
    assert truncated.tolist() == [False, True, False] and not terminated.any()
    assert reward[1] == 0.0
    final = {key: value[1] for key, value in info["final_info"].items()}
    assert final["reason"] == "plant_error"
    assert "instance 1: the model failed at step 3 of episode 1" in final["plant_error"]
    assert "fail_at_step reached" in final["plant_error"]
    assert info["step"].tolist() == [3, 0, 3]  # env 1 starts its next episode (the default scenario)
    for _ in range(5):
        _, _, terminated, truncated, info = env.step(zero)
    assert not (terminated | truncated).any()
    env.close()


def test_a_failing_env_alone_is_truncated_and_reset(tmp_path: Path) -> None:
    exp = experiment_of("typed", tmp_path, TYPED)
    env = BatchVectorEnv(exp, 1)
    env.reset(seed=0, options={"scenario": ["breaks"]})
    zero = np.zeros((1, 1), dtype=np.float32)
    for _ in range(2):
        obs, _, terminated, truncated, info = env.step(zero)
        assert not (terminated | truncated).any()
    _, reward, terminated, truncated, info = env.step(zero)  # doStep 3 fails
    assert truncated.tolist() == [True] and not terminated.any() and reward[0] == 0.0
    np.testing.assert_array_equal(info["final_obs"][0], obs[0])  # the last good observation
    assert info["final_info"]["reason"][0] == "plant_error"
    assert "instance 0: the model failed at step 3 of episode 1" in info["final_info"]["plant_error"][0]
    assert info["step"].tolist() == [0]
    for _ in range(5):
        _, _, terminated, truncated, info = env.step(zero)
    assert not (terminated | truncated).any() and info["step"].tolist() == [5]
    env.close()
    raising = BatchVectorEnv(exp, 1, on_error="raise")
    raising.reset(seed=0, options={"scenario": ["breaks"]})
    raising.step(zero)
    raising.step(zero)
    with pytest.raises(StepError, match="instance 0: the model failed at step 3"):
        raising.step(zero)
    raising.close()


def test_on_error_raise_raises_the_plant_error(tmp_path: Path) -> None:
    from bridge.errors import StepError

    exp = experiment_of("typed", tmp_path, TYPED)
    env = BatchVectorEnv(exp, 2, on_error="raise")
    env.reset(seed=0, options={"scenario": ["breaks", "fine"]})
    zero = np.zeros((2, 1), dtype=np.float32)
    env.step(zero)
    env.step(zero)
    with pytest.raises(StepError, match="instance 0: the model failed at step 3"):
        env.step(zero)
    env.close()


def test_invalid_actions_are_clear_errors() -> None:
    from bridge.errors import BridgeError

    env = BatchVectorEnv(example_experiment("cartpole_continuous"), 2)
    env.reset(seed=0)
    with pytest.raises(BridgeError, match=r"invalid actions for envs \[1\]"):
        env.step(np.array([[0.0], [np.nan]], dtype=np.float32))
    env.close()
    one = BatchVectorEnv(example_experiment("cartpole_balance"), 1)
    one.reset(seed=0)
    with pytest.raises(
        BridgeError, match=r"invalid actions for envs \[0\]: \[2\]; expected elements of Discrete\(2\)"
    ):
        one.step(np.array([2]))
    one.close()


def test_ppo_trains_on_the_batch_vec_env() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    env = VecMonitor(BatchVecEnv(example_experiment("cartpole_balance"), 8))
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=512)
    assert model.num_timesteps >= 512
    env.close()
