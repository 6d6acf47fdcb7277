"""``NodeVectorEnv``: a Gymnasium ``VectorEnv`` over real nodes (subprocesses on a Zenoh router at
127.0.0.1). In either autoreset mode it equals gymnasium's own ``SyncVectorEnv`` over in-process
``FmuEnv`` bit for bit and declares its mode; every action goes out before any answer is awaited;
a node that dies is replaced by a spare (NEXT_STEP: its episode truncated, reset on the next
step); ``claim=True`` leases nodes so that two vector envs on one pool never share a node."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from bridge.env.fmu_env import FmuEnv
from bridge.env.node_vector import NodeVectorEnv
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, node_process

pytestmark = pytest.mark.integration
BALANCE = example_experiment("cartpole_balance")
CONTINUOUS = example_experiment("cartpole_continuous")


@contextmanager
def nodes(experiment: Any, names: list[str], net: Loopback) -> Iterator[list[Any]]:
    with ExitStack() as stack:
        yield [stack.enter_context(node_process(experiment, name, net)) for name in names]


def run(env: Any, steps: int) -> list[tuple[Any, ...]]:
    """Observations, rewards and ends of ``steps`` vector steps under a fixed action pattern."""
    obs, _ = env.reset(seed=11)
    out: list[tuple[Any, ...]] = [(obs.copy(),)]
    for k in range(steps):
        actions = np.array([(k // 3) % 2, (k // 2) % 2])
        obs, reward, terminated, truncated, _ = env.step(actions)
        out.append((obs.copy(), np.asarray(reward, dtype=np.float64), terminated.copy(), truncated.copy()))
    return out


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_node_vector_env_equals_sync_vector_env_bit_for_bit(loopback: Loopback, mode: AutoresetMode) -> None:
    with nodes(BALANCE, ["eq-0", "eq-1"], loopback):
        remote = NodeVectorEnv(
            BALANCE, "eq-*", n_envs=2, autoreset_mode=mode, session=loopback.session, prefix=loopback.prefix
        )
        try:
            assert remote.metadata["autoreset_mode"] is mode and remote.node_names == ["eq-0", "eq-1"]
            ours = run(remote, 120)
        finally:
            remote.close()
    local = gym.vector.SyncVectorEnv([lambda: FmuEnv(BALANCE)] * 2, autoreset_mode=mode)
    try:
        theirs = run(local, 120)
    finally:
        local.close()
    ends = sum(int(t[2].sum() + t[3].sum()) for t in theirs[1:])
    assert ends >= 4  # several episodes ended and were reset within the run
    for k, (a, b) in enumerate(zip(ours, theirs)):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y, err_msg=f"vector step {k}")


def test_every_action_goes_out_before_any_answer_is_awaited(loopback: Loopback) -> None:
    with nodes(BALANCE, ["order-0", "order-1", "order-2"], loopback):
        env = NodeVectorEnv(BALANCE, "order-*", n_envs=3, session=loopback.session, prefix=loopback.prefix)
        try:
            env.reset(seed=0)
            calls: list[str] = []
            for i, inner in enumerate(env.nodes.envs):  # record the calls, then do them
                for name in ("send", "receive"):
                    real = getattr(inner, name)

                    def recorded(*args: Any, _real: Any = real, _tag: str = f"{name}{i}") -> Any:
                        calls.append(_tag)
                        return _real(*args)

                    setattr(inner, name, recorded)
            for _ in range(3):
                calls.clear()
                env.step(np.array([0, 1, 0]))
                assert sorted(calls[:3]) == ["send0", "send1", "send2"], calls
                assert sorted(calls[3:]) == ["receive0", "receive1", "receive2"], calls
        finally:
            env.close()


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_resets_are_all_in_flight_before_any_reply(loopback: Loopback, mode: AutoresetMode) -> None:
    """Every env to reset has sent its request before any reset returns: the first reset waits
    (bounded) until all of them have started, so resets one after the other would fail here."""
    with nodes(BALANCE, ["reset-0", "reset-1", "reset-2"], loopback):
        env = NodeVectorEnv(
            BALANCE,
            "reset-*",
            n_envs=3,
            autoreset_mode=mode,
            session=loopback.session,
            prefix=loopback.prefix,
        )
        calls: list[str] = []
        expected = [0]  # how many resets the next vector call makes
        changed = threading.Condition()
        try:
            for i, inner in enumerate(env.nodes.envs):

                def recorded(*args: Any, _real: Any = inner.reset, _i: int = i, **kwargs: Any) -> Any:
                    with changed:
                        calls.append(f"start{_i}")
                        changed.notify_all()
                        changed.wait_for(lambda: sum(c.startswith("start") for c in calls) >= expected[0], 20)
                    try:
                        return _real(*args, **kwargs)
                    finally:
                        with changed:
                            calls.append(f"end{_i}")

                inner.reset = recorded  # type: ignore[method-assign]
            expected[0] = 3
            env.reset(seed=5)
            assert sorted(calls[:3]) == ["start0", "start1", "start2"], calls
            together = 0
            ended = np.zeros(3, dtype=bool)
            for _ in range(300):
                resets = int(ended.sum()) if mode is AutoresetMode.NEXT_STEP else 0
                calls.clear()
                expected[0] = resets
                _, _, terminated, truncated, _ = env.step(np.zeros(3, dtype=np.int64))  # pushes left: falls
                if mode is AutoresetMode.SAME_STEP:
                    resets = int((terminated | truncated).sum())
                assert len(calls) == 2 * resets
                if resets >= 2:
                    assert all(c.startswith("start") for c in calls[:resets]), calls
                    together += 1
                ended = terminated | truncated
                if together >= 2:
                    break
            assert together >= 2  # several steps reset 2 or 3 envs at once
        finally:
            env.close()


def test_a_dead_node_is_replaced_by_a_spare_under_next_step(loopback: Loopback) -> None:
    with nodes(CONTINUOUS, ["spare-0", "spare-1", "spare-2"], loopback) as processes:
        env = NodeVectorEnv(
            CONTINUOUS,
            "spare-*",
            n_envs=2,
            autoreset_mode="NextStep",
            session=loopback.session,
            prefix=loopback.prefix,
            replace_dead=True,
            timeout_s=10.0,  # the live node's steps keep well inside it on a loaded machine
            replace_wait_s=30.0,
        )
        try:
            obs, _ = env.reset(seed=1)
            action = np.zeros((2, 1), dtype=np.float32)
            before, *_ = env.step(action)
            processes[0].send_signal(signal.SIGKILL)
            processes[0].wait(timeout=10)
            obs, reward, terminated, truncated, infos = env.step(action)
            assert truncated[0] and not terminated[0] and not truncated[1]
            np.testing.assert_array_equal(obs[0], before[0])  # the dead env's last observation
            assert infos["_plant_error"][0] and not infos["_plant_error"][1]
            replaced = infos["node_replaced"]
            assert replaced["dead"][0] == "spare-0" and replaced["new"][0] == "spare-2"
            assert env.node_names == ["spare-2", "spare-1"]
            obs, reward, terminated, truncated, infos = env.step(action)  # NEXT_STEP: env 0 resets
            assert reward[0] == 0.0 and not terminated[0] and not truncated[0] and infos["_drawn"][0]
            for _ in range(5):
                obs, reward, terminated, truncated, infos = env.step(action)
                assert reward[0] > 0  # the spare serves the new episode
        finally:
            env.close()


def test_claimed_nodes_are_never_shared(loopback: Loopback) -> None:
    with nodes(BALANCE, ["pool-0", "pool-1", "pool-2"], loopback):
        kwargs: dict[str, Any] = {"session": loopback.session, "prefix": loopback.prefix, "claim": True}
        first = NodeVectorEnv(BALANCE, "pool-*", n_envs=2, **kwargs)
        second = None
        try:
            second = NodeVectorEnv(BALANCE, "pool-*", n_envs=1, **kwargs, discovery_timeout_s=5.0)
            assert sorted(first.node_names + second.node_names) == ["pool-0", "pool-1", "pool-2"]
            with pytest.raises(ConfigError, match=r"could lease 0 of 1 node\(s\) matching 'pool-\*'"):
                NodeVectorEnv(BALANCE, "pool-*", n_envs=1, **kwargs, discovery_timeout_s=2.0)
            first.reset(seed=0)
            second.reset(seed=0)
            first.step(np.array([0, 1]))
            second.step(np.array([1]))
        finally:
            first.close()
            if second is not None:
                second.close()
