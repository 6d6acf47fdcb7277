"""A RemoteVecEnv that loses a node with no spare: it waits for the same name to come back.

A dead node without a spare once ended the run with PlantDied out of ``step_wait``, the healthy
envs' results of that step lost, and a node restarted under the same name was never picked up.
Now the dead env's episode is truncated, the healthy envs' results are kept, and the env waits up
to ``replace_wait_s`` for a spare or the same name before raising.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from bridge.env import RemoteVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import PlantDied
from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, node_process, stop_process

CARTPOLE = example_experiment("cartpole_continuous")
ACTION = np.full((2, 1), 0.3, dtype=np.float32)


def start_node(name: str, net: Loopback) -> subprocess.Popen[str]:
    args = ["node", str(CARTPOLE), "--name", name, "--connect", net.endpoint, "--prefix", net.prefix]
    return subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def reference(seed: int, steps: int) -> list[np.ndarray]:
    """An env's observations in this process: what its node must give, step for step."""
    with FmuEnv(CARTPOLE) as env:
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for _ in range(steps):
            obs, _, terminated, truncated, _ = env.step(ACTION[0])
            out.append(obs)
            if terminated or truncated:
                obs, _ = env.reset()
                out[-1] = obs
        return out


def test_a_killed_node_restarted_under_its_name_is_picked_up_without_an_exception(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "heal-0", loopback), node_process(CARTPOLE, "heal-1", loopback) as second:
        vec = RemoteVecEnv(
            CARTPOLE,
            ["heal-0", "heal-1"],
            session=loopback.session,
            prefix=loopback.prefix,
            replace_dead=True,
            replace_wait_s=120.0,
            timeout_s=5.0,
        )
        restarted = None
        try:
            vec.seed(7)
            observations = [vec.reset()[0]]
            for _ in range(3):
                observations.append(vec.step(ACTION)[0][0])
            second.send_signal(signal.SIGKILL)
            second.wait(timeout=10)
            restarted = start_node("heal-1", loopback)
            obs, _, dones, infos = vec.step(ACTION)  # waits for heal-1 to come back
            observations.append(obs[0])
            assert dones[1] and infos[1]["TimeLimit.truncated"], infos[1]
            assert (
                infos[1]["node_replaced"]["dead"] == "heal-1" and infos[1]["node_replaced"]["new"] == "heal-1"
            )
            assert not dones[0] and "plant_error" not in infos[0]
            for _ in range(5):
                obs, _, dones, infos = vec.step(ACTION)
                observations.append(obs[0])
                assert "plant_error" not in infos[1]
            expected = reference(7, len(observations) - 1)
            np.testing.assert_array_equal(np.array(observations), np.array(expected))  # env 0: exact
        finally:
            vec.close()
            if restarted is not None:
                stop_process(restarted, timeout_s=10)


def test_without_a_replacement_the_error_comes_after_the_wait_with_the_healthy_results_kept(
    loopback: Loopback,
) -> None:
    with node_process(CARTPOLE, "lone-0", loopback), node_process(CARTPOLE, "lone-1", loopback) as second:
        vec = RemoteVecEnv(
            CARTPOLE,
            "lone-*",
            session=loopback.session,
            prefix=loopback.prefix,
            replace_dead=True,
            replace_wait_s=1.0,
            timeout_s=5.0,
        )
        try:
            vec.reset()
            second.send_signal(signal.SIGKILL)
            second.wait(timeout=10)
            with pytest.raises(
                PlantDied, match=r"no replacement for node 'lone-1' came within replace_wait_s = 1 s"
            ):
                vec.step(ACTION)
            kept = vec.partial_results
            assert kept[1] is None and kept[0] is not None and len(kept[0][0]) == 4, kept
        finally:
            vec.close()


def reference_run(seed: int, steps: int) -> np.ndarray:
    return np.array(reference(seed, steps))


@pytest.mark.slow
def test_soak_four_nodes_one_killed_and_restarted_no_spare(loopback: Loopback) -> None:
    names = [f"soak-{i}" for i in range(4)]
    action = np.full((4, 1), 0.3, dtype=np.float32)
    with (
        node_process(CARTPOLE, names[0], loopback),
        node_process(CARTPOLE, names[1], loopback),
        node_process(CARTPOLE, names[2], loopback) as victim,
        node_process(CARTPOLE, names[3], loopback),
    ):
        vec = RemoteVecEnv(
            CARTPOLE,
            names,
            session=loopback.session,
            prefix=loopback.prefix,
            replace_dead=True,
            replace_wait_s=120.0,
            timeout_s=5.0,
        )
        restarted = None
        try:
            vec.seed(11)
            seen = [vec.reset()]
            replaced = []
            for k in range(300):
                if k == 100:
                    victim.send_signal(signal.SIGKILL)
                    victim.wait(timeout=10)
                    restarted = start_node(names[2], loopback)
                obs, _, _, infos = vec.step(action)  # never raises: the victim comes back
                seen.append(obs)
                replaced += [
                    (k, i, info["node_replaced"]) for i, info in enumerate(infos) if "node_replaced" in info
                ]
            assert [(i, r["dead"], r["new"]) for _, i, r in replaced] == [(2, names[2], names[2])], replaced
            assert replaced[0][0] == 100 and vec.node_names == names
            trajectories = np.array(seen)
            for i in (0, 1, 3):  # the healthy envs: every transition exact
                np.testing.assert_array_equal(trajectories[:, i], reference_run(11 + i, 300))
        finally:
            vec.close()
            if restarted is not None:
                stop_process(restarted, timeout_s=10)
