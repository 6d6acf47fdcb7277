"""A deployed agent without torch: ``agent run --runtime onnx`` (and ``fmu``) as a process in which importing
torch or stable-baselines3 fails (``torch_free/sitecustomize.py``), given only what a robot gets
(the experiment, the model snapshot and ``policy.onnx``), closes the loop with a real cart-pole node
on a Zenoh router at 127.0.0.1 for a whole episode, over the native protocol and the ROS 2 view.

Both processes only ``--connect`` to the router, so both are Zenoh clients by default (the router
reports each session's mode); ``--zenoh-mode peer`` overrides it. The node runs in lockstep: it
waits for every action, so the outcome does not depend on how busy the machine is.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from tests.conftest import Loopback, node_process

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]  # training takes minutes when busy
CARTPOLE = example_experiment("cartpole_balance")
BLOCKER = Path(__file__).parent / "torch_free"
ROOT = Path(__file__).resolve().parents[2]
SUMMARY = re.compile(r"(\d+) observations, (\d+) actions, (\d+) missing-observation events")


@pytest.fixture(scope="module")
def robot_run(balancer: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What goes onto the robot: the run's experiment, model snapshot, ONNX policy and policy FMU,
    no model.zip."""
    from agents.export.onnx import export_onnx
    from agents.export.policy_fmu import export_fmu

    export_onnx(balancer, None)
    fmu = export_fmu(balancer, "2", tmp_path_factory.mktemp("fmu") / "policy-fmi2.fmu")
    robot = tmp_path_factory.mktemp("robot") / "run"
    robot.mkdir()
    shutil.copy2(fmu, robot / fmu.name)
    for name in ("experiment.yaml", "model.json", "policy.onnx"):
        shutil.copy2(balancer / name, robot / name)
    return robot


def torch_free_env(log: Path) -> dict[str, str]:
    """The environment of a process that cannot import torch or stable-baselines3."""
    path = os.pathsep.join([str(BLOCKER), str(ROOT), os.environ.get("PYTHONPATH", "")])
    return {
        **os.environ,
        "PYTHONPATH": path,
        "FMU_BRIDGE_BLOCKED_IMPORTS": str(log),
        "PYTHONUNBUFFERED": "1",
        "COLUMNS": "200",
    }


def test_the_blocker_makes_torch_unimportable(tmp_path: Path) -> None:
    """The control: torch is installed here, and in the blocked environment it does not import."""
    assert importlib.util.find_spec("torch") is not None and importlib.util.find_spec("stable_baselines3")
    log = tmp_path / "blocked.txt"
    for name in ("torch", "stable_baselines3.ppo"):
        result = subprocess.run(
            [sys.executable, "-c", f"import {name}"],
            env=torch_free_env(log),
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        top = name.partition(".")[0]  # the package is refused before its submodule is looked for
        assert result.returncode != 0 and f"{top} is blocked" in result.stderr
    assert log.read_text().startswith("import torch\n") and "import stable_baselines3" in log.read_text()


@contextmanager
def agent_process(
    run: Path, net: Loopback, transport: str, log: Path, *extra: str, runtime: str = "onnx"
) -> Iterator[Any]:
    """``fmu-bridge agent run --runtime onnx|fmu`` in the torch-free environment, up and subscribed."""
    cmd = [sys.executable, "-m", "bridge.cli", "agent", "run", str(run), "--runtime", runtime,
           "--transport", transport, "--node", "plant", "--prefix", net.prefix,
           "--connect", net.endpoint, "--timeout", "120", "--duration", "900", *extra]  # fmt: skip
    process = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=torch_free_env(log)
    )
    try:
        assert process.stdout is not None
        seen = []
        for line in process.stdout:  # ends at exit: a failed start shows its message below
            seen.append(line)
            if "acting on" in line:
                break
        assert process.poll() is None, "agent run exited:\n" + "".join(seen)
        yield process
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)  # the command's own stop: it prints its summary
            try:
                process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=10)


def drive_one_episode(net: Loopback, samples: int) -> list[proto.Frame]:
    """Reset the node for an episode and collect ``samples`` outputs of it.

    The agent's subscription may still be on its way through the router when the first reset
    goes out; then the node waits for an action that never comes, and a new episode is started
    (lockstep: a retry changes nothing the test asserts)."""
    frames: list[proto.Frame] = []
    keys = proto.Keys(net.prefix, "plant")
    sub = net.session.declare_subscriber(  # type: ignore[attr-defined]
        keys.outputs, lambda s: frames.append(proto.decode(s.payload.to_bytes()))
    )
    try:
        for episode in range(10, 20):
            request = {"episode": episode, "values": {"theta0": 0.04}}
            for _ in net.session.get(keys.reset, payload=proto.encode_json(request), timeout=30):  # type: ignore[attr-defined]
                pass
            if _wait_for(frames, episode, 3, 15.0):
                _wait_for(frames, episode, samples, 300.0)
                break
    finally:
        sub.undeclare()
    return [f for f in frames if f.episode == episode and f.kind == proto.OUTPUTS][:samples]


def _wait_for(frames: list[proto.Frame], episode: int, count: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sum(1 for f in frames if f.episode == episode) >= count:
            return True
        time.sleep(0.05)
    return False


def session_modes(net: Loopback) -> list[str]:
    """How each session connected to the router joined it: client or peer."""
    return sorted(str(t.whatami) for t in net.session.info.transports())  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("transport", "mode", "runtime"),
    [
        ("zenoh", "default", "onnx"),
        ("zenoh", "peer", "onnx"),
        ("ros2", "default", "onnx"),
        ("ros2", "peer", "onnx"),
        ("ros2", "default", "fmu"),  # the policy FMU: no torch either
    ],
)
def test_torch_free_agent_keeps_the_pole_up_for_a_whole_episode(  # noqa: PLR0917
    robot_run: Path, loopback: Loopback, tmp_path: Path, transport: str, mode: str, runtime: str
) -> None:
    experiment = load_experiment(CARTPOLE)
    samples = round(experiment.model.episode_duration / experiment.model.sampling_time)
    (_, theta_max), (_, x_max) = experiment.termination.bounds["theta"], experiment.termination.bounds["x"]
    log = tmp_path / "blocked.txt"
    extra = () if mode == "default" else ("--zenoh-mode", mode)
    with (
        node_process(CARTPOLE, "plant", loopback, "--mode", "lockstep", "--ros", *extra),
        agent_process(robot_run, loopback, transport, log, *extra, runtime=runtime) as agent,
    ):
        modes = session_modes(loopback)
        episode = drive_one_episode(loopback, samples)
    output = agent.stdout.read()
    agent.stdout.close()
    assert modes == ["client" if mode == "default" else "peer"] * 2  # node and agent
    assert not log.exists(), f"the deployed agent tried to import torch:\n{log.read_text()}"
    assert agent.returncode == 0, output[-3000:]
    assert len(episode) == samples and [f.step for f in episode] == list(range(samples))
    theta = np.array([f.values[2] for f in episode])
    x = np.array([f.values[0] for f in episode])
    assert np.abs(theta).max() < theta_max and np.abs(x).max() < x_max  # upright the whole episode
    found = SUMMARY.search(" ".join(output.split()))
    assert found is not None, output[-3000:]
    _, actions, missing = map(int, found.groups())
    assert actions >= samples - 1 and missing == 0  # lockstep: nothing is late by design
