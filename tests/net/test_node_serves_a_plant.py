"""A node serves a plant: what it serves is read without the task's code, its plant comes from
the one plant factory, and its answers read the same through a remote env and a system.

Real nodes (in this process or as subprocesses) on a Zenoh router on 127.0.0.1."""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import PlantError, StepTimeout
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.net.remote import describe_nodes
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from bridge.serving import experiment_node
from tests.conftest import Loopback, _wait_for_line, _wait_for_node, stop_process

pytestmark = pytest.mark.integration
CARTPOLE = example_experiment("cartpole_continuous")
ZERO = np.zeros(1, dtype=np.float32)


def variant(tmp_path: Path, name: str, **changes: Any) -> Path:
    """The cart-pole example with top-level sections replaced (``model`` merged)."""
    data = yaml.safe_load(CARTPOLE.read_text())
    model = changes.pop("model", {})
    data["model"] = {**data["model"], **model}
    data.update(changes)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_node_starts_on_an_experiment_whose_reward_callable_it_cannot_import(
    loopback: Loopback, tmp_path: Path
) -> None:
    """The reward runs in the trainer: the node's machine need not carry its code."""
    served = variant(tmp_path, "trainer_only", reward={"callable": "trainer_only_rewards_nowhere:reward"})
    with (
        experiment_node(served, name="no-reward", options=loopback.options(), prefix=loopback.prefix) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(CARTPOLE, "no-reward", session=loopback.session, prefix=loopback.prefix) as remote,
        FmuEnv(CARTPOLE) as local,
    ):
        assert node.describe()["experiment"] == load_experiment(CARTPOLE).name
        np.testing.assert_array_equal(remote.reset(seed=4)[0], local.reset(seed=4)[0])
        for _ in range(5):
            np.testing.assert_array_equal(remote.step(ZERO)[0], local.step(ZERO)[0])


def test_a_node_with_model_isolation_in_its_file_runs_and_reports_it_isolated(
    loopback: Loopback, tmp_path: Path
) -> None:
    isolated = variant(tmp_path, "isolated", model={"isolation": {"timeout": 20.0}})
    with (
        experiment_node(isolated, name="iso", options=loopback.options(), prefix=loopback.prefix) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(
            CARTPOLE, "iso", session=loopback.session, prefix=loopback.prefix, timeout_s=30
        ) as remote,
        FmuEnv(CARTPOLE) as local,
    ):
        assert node.plant.isolated and node.isolated
        described = describe_nodes(loopback.session, ["iso"], prefix=loopback.prefix, timeout_s=10)[0]
        assert described["isolated"] is True
        assert described["can_save_state"] is False and "isolated" in described["save_state_refusal"]
        np.testing.assert_array_equal(remote.reset(seed=1)[0], local.reset(seed=1)[0])
        np.testing.assert_array_equal(remote.step(ZERO)[0], local.step(ZERO)[0])


# -- the same hung node through a remote env and through a system ------------------------------------
SERVE = """
import os, signal, sys, threading
from bridge.experiment.config import load_experiment
from bridge.net.node import FmuNode
from bridge.net.transport import ZenohOptions
from bridge.serving import served_components

file, node, endpoint, prefix, isolate = sys.argv[1:]
component = served_components(load_experiment(file))[node]
server = FmuNode(component.plant, component.served, name=node, prefix=prefix,
                 options=ZenohOptions(connect=(endpoint,)), step_timeout_s=5.0, isolate=isolate == "1")
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
print("serving", flush=True)
stop.wait()
if not server.close():
    os._exit(3)
"""


def typed_system(tmp_path: Path, node: str) -> Path:
    """A system of one typed FMU (it has a String output) served by ``node``, which hangs in the
    doStep of its step 2."""
    data = {
        "name": "hangs",
        "model": {"step_size": 0.1, "episode_duration": 5.0},
        "system": {
            "components": {
                "t": {
                    "fmu": "example:typed",
                    "node": node,
                    "parameters": {"fault_at_step": 2, "fault_kind": 1},
                }
            },
        },
        "actions": {"inputs": ["t.real_in"], "low": {"t.real_in": -1}, "high": {"t.real_in": 1}},
        "observations": {"outputs": ["t.real_out"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    path = tmp_path / f"{node}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@contextlib.contextmanager
def component_node(file: Path, node: str, net: Loopback, isolate: bool) -> Iterator[None]:
    cmd = [sys.executable, "-c", SERVE, str(file), node, net.endpoint, net.prefix, "1" if isolate else "0"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        _wait_for_line(process, "serving", timeout_s=120)
        _wait_for_node(net, node, timeout_s=30)
        yield
    finally:
        stop_process(process, timeout_s=10)


def env_experiment(tmp_path: Path, net: Loopback, node: str) -> Path:
    """A single-FMU experiment with the names the component's node serves (the same plant)."""
    described = describe_nodes(net.session, [node], prefix=net.prefix, timeout_s=10)[0]
    data = {
        "name": "hangs_env",
        "model": {
            "fmu": "example:typed",
            "step_size": 0.1,
            "episode_duration": 5.0,
            "parameters": {"fault_at_step": 2, "fault_kind": 1},
        },
        "actions": {"inputs": ["real_in"], "low": {"real_in": -1}, "high": {"real_in": 1}},
        "observations": {"outputs": described["output_names"], "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    path = tmp_path / "hangs_env.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def after_the_plant(error: BaseException, plant: str) -> str:
    """The message after the plant's name, the watchdog's elapsed time (it varies) left out."""
    message = str(error)
    assert message.startswith(f"{plant}: "), message
    return re.sub(r"for \d+\.\d s \(deadline", "for ... s (deadline", message[len(plant) + 2 :])


@pytest.mark.parametrize("isolate", [False, True], ids=["in_process", "isolated"])
def test_a_hung_node_is_the_same_error_through_a_remote_env_and_through_a_system(
    loopback: Loopback, tmp_path: Path, isolate: bool
) -> None:
    """Same class, same message after the plant's name, the step's own time (not t = 0)."""
    for_env, for_system = typed_system(tmp_path, "hung-env"), typed_system(tmp_path, "hung-sys")
    with (
        component_node(for_env, "hung-env", loopback, isolate),
        component_node(for_system, "hung-sys", loopback, isolate),
    ):
        env = RemoteFmuEnv(
            env_experiment(tmp_path, loopback, "hung-env"),
            "hung-env",
            session=loopback.session,
            prefix=loopback.prefix,
            timeout_s=30,
        )
        remote = NodeComponents(session=loopback.session, prefix=loopback.prefix, timeout_s=30)
        system = FmuEnv(for_system, plant=SystemPlant(load_experiment(for_system), remote=remote))
        try:
            errors: list[PlantError] = []
            for gym_env in (env, system):
                gym_env.reset(seed=0)
                gym_env.step(ZERO)
                with pytest.raises(StepTimeout) as caught:
                    gym_env.step(ZERO)
                errors.append(caught.value)
            through_env, through_system = errors
            component = through_system.__cause__
            assert type(component) is StepTimeout and type(through_env) is StepTimeout
            env_text = after_the_plant(through_env, "node 'hung-env'")
            system_text = after_the_plant(component, "component 't' (node 'hung-sys')")
            assert env_text == system_text.replace("hung-sys", "hung-env")
            assert env_text.startswith("the model hung at step 2 of episode 1 (t = 0.1 s): ")
            assert re.sub(r"for \d+\.\d s", "", through_system.detail) == re.sub(
                r"for \d+\.\d s", "", through_env.detail
            )
            hint = "reset() starts a fresh one" if isolate else "the node is unhealthy until restarted"
            assert env_text.endswith(hint)
        finally:
            env.close()
            system.close()


def test_a_reset_that_names_no_parameter_runs_the_served_experiment(
    loopback: Loopback, tmp_path: Path
) -> None:
    """The node's experiment sets the cart's mass; a client whose own file does not name it (or a
    hand-written request without values) gets the node's value, not the FMU's default: the same
    rule as a ROS reset and a real-time start."""
    fixed: dict[str, Any] = {"randomization": {}, "noise": {}}  # the same start for both files
    plain = variant(tmp_path, "plain", **fixed)
    heavy = variant(tmp_path, "heavy", model={"parameters": {"m_cart": 3.0}}, **fixed)
    with (
        experiment_node(heavy, name="heavy", options=loopback.options(), prefix=loopback.prefix) as node,  # type: ignore[arg-type]
        RemoteFmuEnv(plain, "heavy", session=loopback.session, prefix=loopback.prefix) as remote,
        FmuEnv(heavy) as served,
        FmuEnv(plain) as default,
    ):
        assert node.served.nominal["m_cart"] == 3.0
        trajectories = []
        for env in (remote, served, default):
            env.reset(seed=1)
            trajectory, done = [], False
            while not done and len(trajectory) < 20:
                obs, _, terminated, truncated, _ = env.step(np.ones(1, dtype=np.float32))
                trajectory.append(obs)
                done = terminated or truncated
            trajectories.append(np.array(trajectory))
        np.testing.assert_array_equal(trajectories[0], trajectories[1])
        assert not np.array_equal(trajectories[0], trajectories[2])  # the mass matters here
