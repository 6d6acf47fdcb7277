"""The slow plant (``models/slow_plant``) served by nodes: ``RemoteVecEnv`` and ``NodeVectorEnv``
drive two slow nodes (0.3 s a step, 1 s to initialise) at their default deadlines; resets and
steps slower than the client's ``timeout_s`` succeed (``bridge.net.deadlines``), and a hung one is
reported in bounded time."""

from __future__ import annotations

import contextlib
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from bridge.env import RemoteFmuEnv
from bridge.env.node_vector import NodeVectorEnv
from bridge.env.vec import RemoteVecEnv
from bridge.errors import StepTimeout
from bridge.net.remote import describe_nodes
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


# -- deadlines that follow the plant (bridge.net.deadlines) -----------------------------------------------
@pytest.mark.slow  # 14 s of initialisation
def test_a_first_reset_longer_than_every_deadline_waits_while_the_node_initialises(
    loopback: Loopback, tmp_path: Path
) -> None:
    # an isolated node's first reset has no deadline of its own (it initialises the FMU); the
    # node's other deadlines (2 s), the client's floor (5 s) and Zenoh's default query timeout
    # (10 s) are all shorter than its 14 s
    path = slow_experiment(tmp_path, step_delay_s=0.1, init_delay_s=14.0, duration_s=0.3)
    with (
        node_process(path, "init", loopback, "--isolate", "--step-timeout", "2"),
        RemoteFmuEnv(path, "init", session=loopback.session, prefix=loopback.prefix) as env,
    ):
        deadlines = env.plant.client.deadlines  # type: ignore[attr-defined]
        assert deadlines.reset_s() == 5.0  # nothing measured yet: the floor
        start = time.monotonic()
        obs, _ = env.reset(seed=3)
        took_s = time.monotonic() - start
        x = [float(obs[0])] + [float(env.step(np.array([0.5], dtype=np.float32))[0][0]) for _ in range(2)]
    assert took_s >= 14.0, f"the reset took {took_s:.1f} s: the FMU's initialisation did not run in it"
    np.testing.assert_allclose(x, lag(x[0], 0.5, 2), rtol=0, atol=1e-6)
    assert deadlines.slowest["reset"] >= 14.0 and deadlines.reset_s() >= 56.0  # 4 x the measured reset


def test_steps_slower_than_the_floor_succeed_at_default_deadlines(loopback: Loopback, tmp_path: Path) -> None:
    # 6 s a step: longer than the client's 5 s floor, inside the node's own 10 s deadline
    path = slow_experiment(tmp_path, step_delay_s=6.0, duration_s=0.2)
    with node_process(path, "steps", loopback):
        remote = RemoteVecEnv(path, ["steps"], session=loopback.session, prefix=loopback.prefix)
        try:
            remote.seed(2)
            x0 = float(remote.reset()[0, 0])
            start = time.monotonic()
            obs = remote.step(ACTIONS[:1])[0]
            took_s = time.monotonic() - start
            deadlines = remote.envs[0].plant.client.deadlines  # type: ignore[attr-defined]
        finally:
            remote.close()
    assert took_s >= 6.0, f"the step took {took_s:.1f} s: the delay is not in doStep"
    np.testing.assert_allclose(obs[0, 0], lag(x0, 0.5, 1)[-1], rtol=0, atol=1e-6)
    assert deadlines.step_s() >= 4 * 6.0  # the measured step, with its margin


def test_a_first_reset_longer_than_the_step_timeout_runs_in_an_in_process_node(
    loopback: Loopback, tmp_path: Path
) -> None:
    # the model's initialisation (3 s) is unmeasured before it ends: no deadline, as in an
    # isolated plant, where --step-timeout (1 s) would have reported the node hung
    path = slow_experiment(tmp_path, step_delay_s=0.05, init_delay_s=3.0, duration_s=0.3)
    with (
        node_process(path, "init-in-process", loopback, "--step-timeout", "1"),
        RemoteFmuEnv(path, "init-in-process", session=loopback.session, prefix=loopback.prefix) as env,
    ):
        start = time.monotonic()
        obs, _ = env.reset(seed=3)
        took_s = time.monotonic() - start
        x = [float(obs[0])] + [float(env.step(np.array([0.5], dtype=np.float32))[0][0]) for _ in range(2)]
        (info,) = describe_nodes(loopback.session, ["init-in-process"], prefix=loopback.prefix, timeout_s=10)
    assert took_s >= 3.0, f"the reset took {took_s:.1f} s: the FMU's initialisation did not run in it"
    np.testing.assert_allclose(x, lag(x[0], 0.5, 2), rtol=0, atol=1e-6)
    assert info["health"] == "ok", info


def test_a_reset_hung_in_the_fmu_is_reported_with_the_nodes_words(loopback: Loopback, tmp_path: Path) -> None:
    # the node's first reset (0.3 s) is measured; a later one whose initialisation never returns
    # (a client whose file asks for 1000 s, within what the node's file allows) outlives the
    # node's deadline, max(2 s, 4 x 0.3 s)
    folders = [tmp_path / name for name in ("node", "quick", "stuck")]
    for folder in folders:
        folder.mkdir()
    served = slow_experiment(folders[0])
    served.write_text(served.read_text().replace("x0:", "init_delay_s: {uniform: [0.1, 1000.0]}\n    x0:"))
    quick = slow_experiment(folders[1], init_delay_s=0.3)
    stuck = slow_experiment(folders[2], init_delay_s=1000.0)
    net = {"session": loopback.session, "prefix": loopback.prefix}
    with node_process(served, "stuck-init", loopback, "--step-timeout", "2"):
        with RemoteFmuEnv(quick, "stuck-init", **net) as env:
            env.reset(seed=0)
        with RemoteFmuEnv(stuck, "stuck-init", **net) as env:
            start = time.monotonic()
            with pytest.raises(StepTimeout) as caught:
                env.reset(seed=0)
            took_s = time.monotonic() - start
    message = str(caught.value)
    assert took_s < 60.0, f"a hung reset took {took_s:.0f} s to report"
    assert "the model hung" in message and "has not returned from the reset of episode" in message, message
    assert "--step-timeout" in message, message


def test_a_stopped_node_is_reported_in_bounded_time_during_a_reset(
    loopback: Loopback, tmp_path: Path
) -> None:
    # the client's floor (2 s) and the node's own deadline (1 s + 1 s) end the reset's wait; the
    # stopped node then does not answer info either (2 s): reported before its Zenoh lease ends
    path = slow_experiment(tmp_path)
    with (
        node_process(path, "frozen", loopback, "--step-timeout", "1") as process,
        RemoteFmuEnv(path, "frozen", session=loopback.session, prefix=loopback.prefix, timeout_s=2.0) as env,
    ):
        env.reset(seed=0)
        process.send_signal(signal.SIGSTOP)
        try:
            start = time.monotonic()
            with pytest.raises(StepTimeout) as caught:
                env.reset(seed=1)
            took_s = time.monotonic() - start
        finally:
            process.send_signal(signal.SIGCONT)
    message = str(caught.value)
    assert took_s < 30.0, f"a stopped node took {took_s:.0f} s to report"
    assert "the node did not answer info within 2 s" in message, message
    assert "the deadline 2 s is the longest of timeout_s = 2 s" in message, message
    assert "--step-timeout" in message, message
