"""Experiments with ``model.solver: rk4`` (model exchange integrated in native code): the batch env
equals N single envs bit for bit, and the cart-pole task sees the co-simulation variant's values
(the CS FMU integrates with the same RK4 substeps)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from bridge.env.batch import BatchVectorEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import Experiment, load_experiment
from tests.env.test_batch_env import RICH, actions

N = 4
ME = "model: {fmu: 'example:cartpole:2.0:me', interface: me, solver: rk4, solver_substeps: 10, "


def experiment(tmp_path: Path, model_line: str) -> Experiment:
    text = RICH.replace("model: {fmu: 'example:cartpole', ", model_line)
    assert text != RICH
    path = tmp_path / "me.yaml"
    path.write_text(text)
    return load_experiment(path)


def test_batch_env_over_fixed_step_me_equals_single_envs(tmp_path: Path) -> None:
    exp = experiment(tmp_path, ME)
    assert exp.model.solver == "rk4"
    batch = BatchVectorEnv(exp, N)
    reference = SyncVectorEnv([lambda: FmuEnv(exp) for _ in range(N)], autoreset_mode=AutoresetMode.SAME_STEP)
    obs, _ = batch.reset(seed=3)
    np.testing.assert_array_equal(obs, reference.reset(seed=3)[0])
    rng, ends = np.random.default_rng(2), 0
    for _ in range(150):
        a = actions(batch.single_action_space, rng)[:N]
        got, want = batch.step(a), reference.step(a)
        for mine, theirs in zip(got[:4], want[:4], strict=True):
            np.testing.assert_array_equal(mine, theirs)
        ends += int(np.sum(want[2] | want[3]))
    assert ends > 0  # episodes ended and were reset inside the batch
    batch.close()
    reference.close()


def test_fixed_step_me_env_sees_the_co_simulation_values(tmp_path: Path) -> None:
    envs = [FmuEnv(experiment(tmp_path, line)) for line in (ME, "model: {fmu: 'example:cartpole:2.0:cs', ")]
    first = [env.reset(seed=5)[0] for env in envs]
    np.testing.assert_allclose(first[0], first[1], rtol=0, atol=1e-12)
    rng = np.random.default_rng(0)
    steps = 0
    while steps < 60:
        steps += 1
        a = rng.uniform(-1, 1, size=1).astype(np.float32)
        me, cs = (env.step(a) for env in envs)
        np.testing.assert_allclose(me[0], cs[0], rtol=0, atol=1e-9)
        assert me[1] == pytest.approx(cs[1], abs=1e-9)
        assert me[2:4] == cs[2:4]  # the same termination and truncation
        if me[2] or me[3]:
            break
    assert steps > 5
    for env in envs:
        env.close()
