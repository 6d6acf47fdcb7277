"""The isolated plant: the FMU in a child process, a hang, a crash and a leak become clear errors."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from bridge.env import FmuEnv, PlantVecEnv
from bridge.errors import BridgeError, PlantDied, StepError, StepTimeout
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant

TYPED = """\
model: {fmu: 'example:typed', step_size: 0.1, episode_duration: 5.0}
actions: {inputs: [real_in], low: {real_in: -1}, high: {real_in: 1}}
observations: {outputs: [real_out, counter]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {}
  breaks: {parameters: {fail_at_step: 3}}
  hangs: {parameters: {fault_at_step: 3, fault_kind: 1}}
  crashes: {parameters: {fault_at_step: 3, fault_kind: 2}}
  leaks: {parameters: {fault_at_step: 1, fault_kind: 3}}
schedule: {mode: fixed}
"""
ZERO = np.zeros(1, dtype=np.float32)


@pytest.fixture(scope="module")
def typed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("isolated") / "typed.yaml"
    path.write_text(TYPED)
    return path


def isolated_env(path: Path, **kwargs: float) -> FmuEnv:
    experiment = load_experiment(path)
    return FmuEnv(experiment, plant=IsolatedFmuPlant(experiment_plant_spec(experiment), **kwargs))  # type: ignore[arg-type]


def steps(env: FmuEnv, scenario: str, n: int) -> list[np.ndarray]:
    obs, _ = env.reset(seed=1, options={"scenario": scenario})
    out = [obs]
    for _ in range(n):
        out.append(env.step(ZERO)[0])
    return out


def test_isolated_plant_gives_the_in_process_trajectory_bit_for_bit() -> None:
    experiment = example_experiment("cartpole_continuous")
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(60, 1)).astype(np.float32)

    def run(env: FmuEnv) -> np.ndarray:
        rows = [env.reset(seed=3)[0]]
        for a in actions:
            obs, _, terminated, truncated, _ = env.step(a)
            rows.append(obs)
            if terminated or truncated:
                rows.append(env.reset()[0])
        return np.array(rows)

    with FmuEnv(experiment) as local:
        expected = run(local)
    exp = load_experiment(experiment)
    with FmuEnv(exp, plant=IsolatedFmuPlant(experiment_plant_spec(exp))) as isolated:
        np.testing.assert_array_equal(run(isolated), expected)


def test_a_failed_step_is_the_same_step_error_as_in_process(typed: Path) -> None:
    errors = []
    for env in (FmuEnv(typed), isolated_env(typed)):
        with env, pytest.raises(StepError) as caught:
            steps(env, "breaks", 3)
        errors.append(caught.value)
    shape = (
        r"FMU typed\S*\.fmu \((in-process|child process)\): the model failed at step 3 of episode 1 "
        r"\(t = 0\.2 s\): typed: doStep returned Error.*; check the model's parameters.*fail_at_step reached"
    )
    for error in errors:
        assert re.match(shape, str(error), re.S), str(error)
    assert errors[0].detail == errors[1].detail and errors[0].log == errors[1].log


def test_a_hung_fmu_times_out_and_the_next_reset_starts_a_fresh_process(typed: Path) -> None:
    # 5 s: the hang meets it; the reset and the steps around it, in a fresh process after the
    # hang, keep well inside it on a loaded machine
    with isolated_env(typed, timeout_s=5.0) as env:
        start = time.monotonic()
        with pytest.raises(
            StepTimeout, match=r"child process\): no answer within 5 s at step 3 of episode 1"
        ):
            steps(env, "hangs", 5)
        assert time.monotonic() - start < 30  # the deadline, not forever (generous: busy machines)
        with pytest.raises(BridgeError, match="call reset"):
            env.step(ZERO)
        assert len(steps(env, "fine", 10)) == 11  # restarted
        assert env.plant.restarts == 1  # type: ignore[attr-defined]


def test_a_segfaulting_fmu_is_a_clear_error_not_a_dead_trainer(typed: Path) -> None:
    with isolated_env(typed) as env:
        with pytest.raises(PlantDied, match=r"the plant died at step 3 of episode 1: .*killed by SIGSEGV"):
            steps(env, "crashes", 5)
        assert len(steps(env, "fine", 10)) == 11


def test_a_leaking_fmu_is_stopped_at_its_memory_limit(typed: Path) -> None:
    with isolated_env(typed, memory_limit_mb=16) as env:
        with pytest.raises(PlantDied, match=r"exceeded its memory limit.*grew by \d+ MB.*leaks memory"):
            steps(env, "leaks", 49)  # 1 MiB per step: past 16 MB at the check of sample 32
        assert len(steps(env, "fine", 10)) == 11


def test_vector_env_truncates_the_episode_of_a_hung_plant_and_goes_on(typed: Path) -> None:
    envs = [isolated_env(typed, timeout_s=5.0) for _ in range(2)]  # the fine one's steps: well inside
    vec = PlantVecEnv(envs, on_error="truncate")
    try:
        vec.set_options([{"scenario": "hangs"}, {"scenario": "fine"}])
        vec.reset()
        dones_at = []
        for k in range(4):
            _, _, dones, infos = vec.step(np.zeros((2, 1), dtype=np.float32))
            if dones[0]:
                dones_at.append(k)
                assert "no answer within 5 s" in infos[0]["plant_error"] and infos[0]["TimeLimit.truncated"]
            assert not dones[1]
        assert dones_at == [2]
    finally:
        vec.close()


def test_model_isolation_in_the_experiment_file_gives_the_isolated_plant(tmp_path: Path) -> None:
    path = tmp_path / "isolated.yaml"
    path.write_text(
        TYPED.replace("episode_duration: 5.0}", "episode_duration: 5.0, isolation: {timeout: 5}}")
    )
    with FmuEnv(path) as env:
        assert isinstance(env.plant, IsolatedFmuPlant) and env.plant.timeout_s == 5.0
        with pytest.raises(StepTimeout, match="no answer within 5 s"):
            steps(env, "hangs", 5)
