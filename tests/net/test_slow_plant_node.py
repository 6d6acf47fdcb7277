"""The slow plant (``models/slow_plant``) served by nodes: ``RemoteVecEnv`` and ``NodeVectorEnv``
drive two slow nodes (0.3 s a step, 1 s to initialise) at their default deadlines."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

from bridge.env.node_vector import NodeVectorEnv
from bridge.env.vec import RemoteVecEnv
from tests.conftest import Loopback, node_process
from tests.plant.test_slow_plant import lag
from tests.slow_plant import slow_experiment

pytestmark = pytest.mark.integration  # node processes, a Zenoh router on 127.0.0.1

ACTIONS = np.full((2, 1), 0.5, dtype=np.float32)


@pytest.mark.parametrize("vec", ["RemoteVecEnv", "NodeVectorEnv"])
def test_vector_envs_over_slow_nodes_follow_the_plants_equation(
    loopback: Loopback, tmp_path: Path, vec: str
) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.3, init_delay_s=1.0, duration_s=0.5)
    net = {"session": loopback.session, "prefix": loopback.prefix}
    with contextlib.ExitStack() as stack:
        for name in ("slow-0", "slow-1"):
            stack.enter_context(node_process(path, name, loopback))
        if vec == "RemoteVecEnv":
            remote = RemoteVecEnv(path, "slow-*", n_envs=2, **net)
            stack.callback(remote.close)
            remote.seed(5)
            x0 = remote.reset()[:, 0].copy()
            for _ in range(2):
                obs = remote.step(ACTIONS)[0]
        else:
            nodes = NodeVectorEnv(path, "slow-*", n_envs=2, **net)
            stack.callback(nodes.close)
            x0 = nodes.reset(seed=5)[0][:, 0].copy()
            for _ in range(2):
                obs = nodes.step(ACTIONS)[0]
    expected = [lag(float(x), 0.5, 2)[-1] for x in x0]
    np.testing.assert_allclose(obs[:, 0], expected, rtol=0, atol=1e-6)
    assert x0[0] != x0[1], "each node drew its own initial state"
