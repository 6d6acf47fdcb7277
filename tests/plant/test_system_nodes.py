"""Systems with components served by nodes: real `fmu-bridge system serve` subprocesses on 127.0.0.1.

The same seed gives the same trajectory whether the components run in this process, in nodes,
or mixed, under Jacobi and Gauss-Seidel; a component node that dies is reported by name.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError, PlantDied, StepTimeout
from bridge.experiment.config import load_experiment
from bridge.net import protocol as proto
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from tests.conftest import Loopback, _wait_for_line, _wait_for_node, stop_process

pytestmark = pytest.mark.integration
EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"
NODES = {"controller": "ctrl-node", "motor": "motor-node", "load": "load-node"}


def system_file(directory: Path, name: str, nodes: dict[str, str], algorithm: str = "jacobi") -> Path:
    """The example system with ``node:`` on the components in ``nodes``."""
    data = yaml.safe_load(EXAMPLE.read_text())
    data["system"]["algorithm"] = algorithm
    for component, node in nodes.items():
        data["system"]["components"][component]["node"] = node
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@contextlib.contextmanager
def serve(
    file: Path, net: Loopback, *components: str, extra: tuple[str, ...] = ()
) -> Iterator[subprocess.Popen[str]]:
    """``fmu-bridge system serve`` as a real subprocess (``extra``: more options), stopped (and
    reaped) at the end."""
    chosen = [a for c in components for a in ("--component", c)]
    cmd = [sys.executable, "-m", "bridge.cli", "system", "serve", str(file), "--connect", net.endpoint]
    cmd += ["--prefix", net.prefix, *chosen, *extra]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        _wait_for_line(process, "component node(s) serving", timeout_s=120)
        data = yaml.safe_load(file.read_text())["system"]["components"]
        for name in components or [c for c in data if "node" in data[c]]:
            _wait_for_node(net, data[name]["node"], timeout_s=30)
        yield process
    finally:
        stop_process(process, timeout_s=20)


@pytest.fixture(scope="module")
def served(net: Loopback, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Every component of the example system in its own node (one serve process)."""
    directory = tmp_path_factory.mktemp("system_nodes")
    with serve(system_file(directory, "served", NODES), net):
        yield directory


def trajectory(env: Any, seed: int, steps: int = 25) -> np.ndarray:
    obs, info = env.reset(seed=seed)
    rows = [np.append(obs, info["time_s"])]
    for i in range(steps):
        action = np.array([0.8 * np.sin(0.3 * i + seed)], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        rows.append(np.append(obs, [reward, info["time_s"], *info["outputs"]]).astype(np.float64))
        if terminated or truncated:
            break
    return np.concatenate(rows)


def remote_env(file: Path, net: Loopback) -> FmuEnv:
    remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)
    plant = SystemPlant(load_experiment(file), remote=remote)
    return FmuEnv(file, plant=plant)


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss_seidel"])
@pytest.mark.parametrize("remote", [["motor", "load"], ["controller", "motor", "load"]], ids=["mixed", "all"])
def test_nodes_give_the_in_process_trajectory(
    served: Path, net: Loopback, algorithm: str, remote: list[str]
) -> None:
    here = system_file(served, f"here_{algorithm}", {}, algorithm)
    there = system_file(served, f"there_{algorithm}_{len(remote)}", {c: NODES[c] for c in remote}, algorithm)
    with FmuEnv(here) as local, remote_env(there, net) as distributed:
        assert all(
            type(p).__name__ == "RemotePlant" for n, p in distributed.plant.plants.items() if n in remote
        )
        for seed in (0, 3, 0):  # the repeat: reset restores the whole system
            expected, got = trajectory(local, seed), trajectory(distributed, seed)
            np.testing.assert_array_equal(got, expected)
        assert np.max(np.abs(expected)) > 1.0  # the motor really turned


def test_a_node_component_needs_no_fmu_on_this_machine(served: Path, net: Loopback) -> None:
    here = system_file(served, "here_nofmu", {})
    there = system_file(served, "there_nofmu", {"motor": NODES["motor"]})
    data = yaml.safe_load(there.read_text())
    data["system"]["components"]["motor"]["fmu"] = "only/on/the/node/dcmotor.fmu"
    there.write_text(yaml.safe_dump(data))
    with FmuEnv(here) as local, remote_env(there, net) as distributed:
        motor = distributed.plant.plants["motor"]  # type: ignore[attr-defined]
        fmu = distributed.plant.system.components["motor"].fmu  # type: ignore[attr-defined]
        assert not fmu.exists() and "omega" in motor.info.variables
        np.testing.assert_array_equal(trajectory(distributed, 2), trajectory(local, 2))


def test_a_dead_component_node_is_named(net: Loopback, tmp_path: Path) -> None:
    file = system_file(tmp_path, "dying", {"load": "dying-load"})
    own = Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)
    with serve(file, own, "load") as process, remote_env(file, own) as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
        with pytest.raises(PlantDied, match=r"component 'load' \(node 'dying-load'\) died") as caught:
            for _ in range(1000):  # the first step after the death notice raises; bounded anyway
                env.step(env.action_space.sample())
        assert caught.value.component == "load"  # type: ignore[attr-defined]


def test_a_component_node_that_is_not_running_is_a_clear_error(net: Loopback, tmp_path: Path) -> None:
    file = system_file(tmp_path, "absent", {"motor": "nobody-home"})
    with pytest.raises(Exception, match=r"no node 'nobody-home' answers") as info:
        remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=1.0)
        SystemPlant(load_experiment(file), remote=remote)
    assert "`fmu-bridge system serve EXPERIMENT --component motor`" in str(info.value)


def test_serving_a_component_without_node_is_refused(tmp_path: Path) -> None:
    from bridge.serving.system import serve_components

    file = system_file(tmp_path, "none", {"motor": "m"})
    with pytest.raises(ConfigError, match=r"\['load'\] is not served by a node"):
        serve_components(load_experiment(file), ["load"])


# -- the master's answers channel (bridge.net.channel): overdue, dead, flooded -------------------------
def test_a_stopped_node_times_out_and_the_next_episode_steps_again(net: Loopback, tmp_path: Path) -> None:
    file = system_file(tmp_path, "stopped", {"load": "stopped-load"})
    own = Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)
    remote = NodeComponents(session=own.session, prefix=own.prefix, timeout_s=5.0)
    here = system_file(tmp_path, "stopped_here", {})
    # the node's own deadline under the client's 5 s: the client's deadline is then its floor
    with serve(file, own, "load", extra=("--step-timeout", "2")) as process, FmuEnv(here) as local:
        env = FmuEnv(file, plant=SystemPlant(load_experiment(file), remote=remote))
        try:
            env.reset(seed=1)
            env.step(env.action_space.sample())
            process.send_signal(signal.SIGSTOP)
            try:
                start = time.monotonic()
                with pytest.raises(
                    StepTimeout,
                    match=r"component 'load' \(node 'stopped-load'\) did not answer .*"
                    r"no outputs for step 11 within [\d.]+ s \(the deadline 5 s is the longest of "
                    r"timeout_s = 5 s, the node's own deadline 2 s \+ 1 s",
                ):
                    env.step(env.action_space.sample())
                assert 4.9 < time.monotonic() - start < 60  # the watchdog ended the wait, not before
            finally:
                process.send_signal(signal.SIGCONT)
            # the channel the watchdog closed is opened again: the next episode is the in-process one
            np.testing.assert_array_equal(trajectory(env, 4), trajectory(local, 4))
        finally:
            env.close()


def test_a_node_killed_during_a_step_is_reported_before_the_timeout(net: Loopback, tmp_path: Path) -> None:
    file = system_file(tmp_path, "killed", {"motor": "killed-motor"})
    own = Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)
    with serve(file, own, "motor") as process, remote_env(file, own) as env:  # timeout 60 s
        env.reset(seed=0)
        env.step(env.action_space.sample())
        process.send_signal(signal.SIGSTOP)  # the next step waits for an answer that never comes
        killer = threading.Timer(1.0, process.send_signal, (signal.SIGKILL,))
        killer.start()
        start = time.monotonic()
        with pytest.raises(PlantDied, match=r"component 'motor' \(node 'killed-motor'\) died"):
            env.step(env.action_space.sample())
        assert time.monotonic() - start < 30  # the death ended the wait, not the 60 s timeout
        killer.join()


def test_stray_frames_on_a_nodes_outputs_key_do_not_disturb_a_step(served: Path, net: Loopback) -> None:
    here = system_file(served, "here_stray", {})
    there = system_file(served, "there_stray", {"load": NODES["load"]})
    publisher = net.session.declare_publisher(proto.Keys(net.prefix, NODES["load"]).outputs)  # type: ignore[attr-defined]
    stray = [b"", b"\x00" * 7, b"not a frame" * 30]
    stray += [proto.encode_values(proto.OUTPUTS, e, s, 0, [9.0, 9.0]) for e in (0, 99) for s in range(40)]

    class Flooded(gymnasium.Wrapper):  # type: ignore[type-arg]
        def step(self, action: Any) -> Any:
            for payload in stray:  # more than the channel holds: the oldest are dropped
                publisher.put(payload)
            return self.env.step(action)

    try:
        with FmuEnv(here) as local, remote_env(there, net) as distributed:
            np.testing.assert_array_equal(trajectory(Flooded(distributed), 5), trajectory(local, 5))
    finally:
        publisher.undeclare()
