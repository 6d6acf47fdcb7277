"""BatchVectorEnv in both autoreset modes, per sub-env: NEXT_STEP against gymnasium's SyncVectorEnv
over N FmuEnv in NEXT_STEP (bit for bit), and every episode read back the way a NEXT_STEP consumer
(RLlib's env runner) reads it: its terminal observation is the FMU's terminal state and it has every
step the FMU took. SAME_STEP is what the env declares by default."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from bridge.env.batch import BatchVectorEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, load_experiment
from bridge.experiment.examples import example_experiment
from tests.env.episodes import episodes_next_step, replay_in_fmu_env
from tests.env.test_batch_env import TYPED  # the typed model with a step that fails

N = 4
STEPS = 400


def cartpole() -> Experiment:
    return load_experiment(example_experiment("cartpole_balance"))


def test_batch_vector_env_declares_same_step_by_default_and_next_step_when_asked() -> None:
    same = BatchVectorEnv(cartpole(), 2)
    nxt = BatchVectorEnv(cartpole(), 2, autoreset_mode=AutoresetMode.NEXT_STEP)
    by_value = BatchVectorEnv(cartpole(), 2, autoreset_mode="NextStep")
    try:
        assert same.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
        assert nxt.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert by_value.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert BatchVectorEnv.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP  # class untouched
    finally:
        same.close()
        nxt.close()
        by_value.close()


@pytest.mark.parametrize("mode", [AutoresetMode.DISABLED, "next", 3])
def test_an_autoreset_mode_not_offered_is_refused_with_the_choices(mode: Any) -> None:
    with pytest.raises(ConfigError, match=r"autoreset_mode must be one of.*NextStep"):
        BatchVectorEnv(cartpole(), 2, autoreset_mode=mode)


def test_autoreset_is_not_a_vector_env_argument() -> None:
    with pytest.raises(ConfigError, match="autoreset_mode"):
        BatchVectorEnv(cartpole(), 2, autoreset=False)


@pytest.mark.parametrize(
    ("native", "n"), [(True, N), (False, N), (True, 1)], ids=["native", "python", "one-env"]
)
@pytest.mark.parametrize("name", ["cartpole_balance", "cartpole_continuous", "dcmotor_tracking"])
def test_next_step_equals_sync_vector_env_over_fmu_envs_in_next_step(name: str, native: bool, n: int) -> None:
    """With actuator and sensor noise, reference tables and continuous actions too; a batch of
    one (RLlib's runner over one FMU) steps through the scalar Task and is checked the same."""
    exp = load_experiment(example_experiment(name))
    batch = BatchVectorEnv(exp, n, autoreset_mode=AutoresetMode.NEXT_STEP, native=native)
    reference = SyncVectorEnv([lambda: FmuEnv(exp) for _ in range(n)], autoreset_mode=AutoresetMode.NEXT_STEP)
    try:
        np.testing.assert_array_equal(batch.reset(seed=11)[0], reference.reset(seed=11)[0])
        rng = np.random.default_rng(5)
        resets = 0
        space = batch.single_action_space
        for _ in range(700 if name == "dcmotor_tracking" else STEPS):
            if isinstance(space, gym.spaces.Discrete):
                a = rng.integers(0, 2, size=n)
            else:
                a = rng.uniform(-1.3, 1.3, size=(n, *space.shape)).astype(np.float32)
            obs, reward, terminated, truncated, info = batch.step(a)
            r_obs, r_reward, r_terminated, r_truncated, _ = reference.step(a)
            np.testing.assert_array_equal(obs, r_obs)
            np.testing.assert_array_equal(reward, r_reward)
            np.testing.assert_array_equal(terminated, r_terminated)
            np.testing.assert_array_equal(truncated, r_truncated)
            if "_scenario" in info:
                resets += int(info["_scenario"].sum())
            assert "final_obs" not in info, "NEXT_STEP has no final_obs: the last obs is the obs"
        assert resets >= n, "too few episodes ended: the test would not cover the next-step reset"
    finally:
        batch.close()
        reference.close()


def test_next_step_episodes_end_in_the_fmus_terminal_state_and_lose_no_step() -> None:
    exp = cartpole()
    env = BatchVectorEnv(exp, N, autoreset_mode=AutoresetMode.NEXT_STEP)
    names = env.engine.task.output_names
    observed = [names.index(name) for name in ("x", "x_dot", "theta", "theta_dot")]  # the obs, raw
    try:
        per_env = episodes_next_step(env, seed=3, steps=STEPS, rng=np.random.default_rng(8))
    finally:
        env.close()
    finished = 0
    for i, episodes in enumerate(per_env):
        for episode in episodes:
            if episode.end is None:
                continue
            finished += 1
            # the terminal observation is the FMU's outputs at its last step (raw scale)
            outputs = episode.end["outputs"]
            np.testing.assert_array_equal(episode.obs[-1], np.asarray(outputs, np.float32)[observed])
            assert len(episode.actions) == episode.end["step"], f"env {i} lost a step"
        replay_in_fmu_env(exp, seed=3 + i, episodes=episodes)
    assert finished >= 2 * N


def test_same_step_read_as_next_step_shows_the_mismatch() -> None:
    """What RLlib did with the SAME_STEP env: the 'terminal' obs is the next reset state and the next
    episode lacks its first step. The check used above catches exactly that."""
    exp = cartpole()
    env = BatchVectorEnv(exp, N)  # SAME_STEP
    try:
        per_env = episodes_next_step(env, seed=3, steps=STEPS, rng=np.random.default_rng(8))
    finally:
        env.close()
    with pytest.raises(AssertionError):
        replay_in_fmu_env(exp, seed=3, episodes=per_env[0])


def test_next_step_a_plant_error_truncates_that_env_only_and_it_resets_on_the_next_step(
    tmp_path: Path,
) -> None:
    path = tmp_path / "typed.yaml"
    path.write_text(TYPED)
    env = BatchVectorEnv(load_experiment(path), 2, autoreset_mode=AutoresetMode.NEXT_STEP)
    try:
        env.reset(seed=0, options={"scenario": ["fine", "breaks"]})
        a = np.zeros((2, 1), dtype=np.float32)
        for _ in range(2):
            _, _, terminated, truncated, _ = env.step(a)
            assert not (terminated | truncated).any()
        _, reward, terminated, truncated, info = env.step(a)  # env 1's third step fails
        assert list(truncated) == [False, True] and not terminated.any()
        assert "fail" in str(info["plant_error"][1]) and not info["_plant_error"][0]
        assert info["reason"][1] == "plant_error"
        _, reward, terminated, truncated, info = env.step(a)  # env 1 resets, env 0 steps on
        assert reward[1] == 0.0 and not (terminated | truncated).any()
        assert list(info["step"]) == [4, 0] and info["_scenario"][1]
    finally:
        env.close()
