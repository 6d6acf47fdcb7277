"""A RemoteVecEnv that loses a node with no spare: it waits for the same name to come back.

A dead node without a spare once ended the run with PlantDied out of ``step_wait``, the healthy
envs' results of that step lost, and a node restarted under the same name was never picked up.
Now the dead env's episode is truncated, the healthy envs' results are kept, and the env waits up
to ``replace_wait_s`` for a spare or the same name before raising.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

import numpy as np
import pytest

from bridge.env import RemoteVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import PlantDied
from bridge.experiment.examples import example_experiment
from bridge.experiment.sections import REPLACE_WAIT_S
from bridge.serving import experiment_node
from tests.conftest import Loopback, node_process, stop_process
from tests.net.soak import soak, start_node

CARTPOLE = example_experiment("cartpole_continuous")
ACTION = np.full((2, 1), 0.3, dtype=np.float32)


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


@pytest.mark.slow
def test_soak_four_nodes_killed_and_restarted_in_turn_no_spare_every_transition_exact(
    loopback: Loopback,
) -> None:
    """The acceptance soak, bounded for CI (``python -m tests.net.soak --seconds 180`` is the long
    form): 4 nodes, a node killed and restarted under its name every 12 s, no spare."""
    report = soak(loopback, seconds=40.0, kill_every_s=12.0)
    print(report.summary())
    assert len(report.kills) == 3 and report.steps > 0, report.summary()
    assert [(k, dead, new) for k, _, dead, new in report.replaced] == [(k, v, v) for k, v in report.kills]
    assert [i for _, i, _, _ in report.replaced] == [2, 3, 0]
    assert report.transitions == 4 * report.steps and not report.mismatches, report.mismatches[:5]


def test_a_node_found_dead_at_a_reset_is_replaced_and_the_episode_drawn_is_the_undisturbed_one(
    loopback: Loopback,
) -> None:
    """The dead node's env draws its episode before the reset fails; the replacement draws it
    again from the same state, so the run's episodes are those of a run without the death."""
    with node_process(CARTPOLE, "redraw-0", loopback), node_process(CARTPOLE, "redraw-1", loopback) as second:
        vec = RemoteVecEnv(
            CARTPOLE,
            ["redraw-0", "redraw-1"],
            session=loopback.session,
            prefix=loopback.prefix,
            replace_dead=True,
            replace_wait_s=120.0,
            timeout_s=5.0,
        )
        restarted = None
        try:
            vec.seed(21)
            vec.reset()
            for _ in range(3):
                vec.step(ACTION)
            second.send_signal(signal.SIGKILL)
            second.wait(timeout=10)
            restarted = start_node("redraw-1", loopback)
            observations = vec.reset()  # env 1's reset meets the dead node, then its replacement
            replaced = vec.reset_infos[1].get("node_replaced")
            assert replaced is not None and replaced["new"] == "redraw-1", vec.reset_infos[1]
            for i in range(2):
                with FmuEnv(CARTPOLE) as local:
                    local.reset(seed=21 + i)
                    for _ in range(3):
                        local.step(ACTION[0])
                    np.testing.assert_array_equal(observations[i], local.reset()[0])
        finally:
            vec.close()
            if restarted is not None:
                stop_process(restarted, timeout_s=10)


@pytest.mark.integration
def test_by_default_a_node_restarted_under_its_name_replaces_itself(loopback: Loopback) -> None:
    """``replace_wait_s`` once defaulted to 0: PlantDied the moment a node died, though the same
    node restarted under its name would have replaced itself. The default now waits (30 s)."""
    from bridge.net.node import FmuNode

    options: Any = loopback.options()
    first = experiment_node(CARTPOLE, name="again-0", options=options, prefix=loopback.prefix)
    second = experiment_node(CARTPOLE, name="again-1", options=options, prefix=loopback.prefix)
    restarted: list[FmuNode] = []
    vec = RemoteVecEnv(
        CARTPOLE, ["again-0", "again-1"], session=loopback.session, prefix=loopback.prefix, replace_dead=True
    )
    try:
        assert vec.replace_wait_s == REPLACE_WAIT_S >= 10
        vec.reset()
        second.close()  # the node stops; the same name comes back as soon as its FMU is loaded
        thread = threading.Thread(
            target=lambda: restarted.append(
                experiment_node(CARTPOLE, name="again-1", options=options, prefix=loopback.prefix)
            )
        )
        thread.start()
        _, _, dones, infos = vec.step(ACTION)
        assert dones[1] and infos[1]["node_replaced"] == {**infos[1]["node_replaced"], "new": "again-1"}
        thread.join()
    finally:
        vec.close()
        for node in (first, *restarted):
            node.close()
