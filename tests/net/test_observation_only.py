"""An observation-only experiment (no inputs, no tunable parameters) over the network and recording paths.

``init`` on the bouncing ball (FMI 2.0 CS: parameters only, all fixed) writes ``actions: {inputs: []}``.
That experiment is served by a real ``fmu-bridge node`` on a Zenoh router on 127.0.0.1, stepped by a
remote env under the ``zero`` policy, recorded twice (``fmu-bridge record --node`` as a subprocess and
the env wrapped in ``RecordMcap``), read back with rosbags and replayed headless with ``replay --save``.
References: the same experiment in process, the free-fall closed form and rosbags' decoder.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.cli.simulate import make_policy
from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.init import starting_config
from bridge.recording.env_recorder import RecordMcap
from tests.conftest import (
    Loopback,
    example_fmu,
    free_port,
    node_process,
    wait_for_recorded,
    wait_for_recorder,
)

pytestmark = pytest.mark.integration
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
STEPS = 60  # 0.6 s at 10 ms: the fall and the first bounce (t1 = sqrt(2 h0 / g) = 0.4515 s)
G, H0 = 9.81, 1.0
_load_plugins()


@dataclass
class Run:
    experiment: Path
    node_file: Path  # ``fmu-bridge record --node``
    env_file: Path  # RecordMcap around the remote env
    outputs: list[np.ndarray]  # what the remote env received: the reset reply, then every step
    rewards: list[float]


def _drive(env: Any, outputs: list[np.ndarray], rewards: list[float]) -> None:
    policy = make_policy("zero", env.unwrapped.task, 0)
    obs, info = env.reset(seed=0)
    outputs.append(np.array(info["outputs"], dtype=np.float64))
    for _ in range(STEPS):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        outputs.append(np.array(info["outputs"], dtype=np.float64))
        rewards.append(float(reward))
        assert not (terminated or truncated)


def _stop(recorder: subprocess.Popen[str]) -> str:
    recorder.send_signal(signal.SIGINT)
    try:
        out, err = recorder.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        recorder.kill()  # never leave a recorder behind
        recorder.communicate(timeout=10)
        raise
    assert recorder.returncode == 0, err
    return out


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    from bridge.net.transport import ZenohOptions, open_session

    folder = tmp_path_factory.mktemp("observation_only")
    experiment = folder / "ball.yaml"
    experiment.write_text(starting_config(example_fmu("bouncing_ball", "2.0", "cs"), relative_to=folder))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    net = Loopback(endpoint, f"test_{uuid.uuid4().hex[:10]}", session)
    result = Run(experiment, folder / "node.mcap", folder / "env.mcap", [], [])
    try:
        with node_process(experiment, "ball", net):
            recorder = subprocess.Popen(
                [sys.executable, "-m", "bridge.cli", "record", "--node", "ball", "-o", str(result.node_file),
                 "--connect", endpoint, "--prefix", net.prefix],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
            )  # fmt: skip
            try:
                wait_for_recorder(net, "ball")
                remote = RemoteFmuEnv(experiment, "ball", session=session, prefix=net.prefix)
                with RecordMcap(remote, result.env_file, agent="zero") as env:
                    _drive(env, result.outputs, result.rewards)
                wait_for_recorded(net, "ball", {"outputs": STEPS + 1})  # the reset's step 0 too
            finally:
                out = _stop(recorder)
        assert "wrote" in out
        yield result
    finally:
        session.close()  # type: ignore[attr-defined]


def positions(path: Path, topic: str) -> np.ndarray:
    """The JointState positions of ``topic``, decoded by rosbags (an independent reader)."""
    with AnyReader([path]) as reader:
        rows = [
            np.asarray(reader.deserialize(raw, c.msgtype).position, dtype=np.float64)
            for c, _, raw in reader.messages()
            if c.topic == topic
        ]
    return np.array(rows)


def test_init_writes_an_observation_only_experiment(run: Run) -> None:
    data = yaml.safe_load(run.experiment.read_text())
    assert data["actions"] == {"inputs": []}
    assert data["observations"]["outputs"] == ["h", "v", "bounces"]


def test_remote_env_on_a_real_node_gives_the_in_process_trajectory(run: Run) -> None:
    local: list[np.ndarray] = []
    with FmuEnv(run.experiment) as env:
        _drive(env, local, [])
    np.testing.assert_array_equal(np.array(run.outputs), np.array(local))
    assert run.rewards == [1.0] * STEPS  # init's reward: alive
    t = np.arange(STEPS + 1) * 0.01
    falling = t < np.sqrt(2 * H0 / G)
    heights = np.array(run.outputs)[falling, 0]
    np.testing.assert_allclose(heights, H0 - G * t[falling] ** 2 / 2, rtol=0, atol=1e-12)
    assert np.array(run.outputs)[-1, 2] == 1  # one bounce by 0.6 s


def test_node_and_env_recordings_hold_what_the_env_received(run: Run) -> None:
    received = np.array(run.outputs)
    np.testing.assert_array_equal(positions(run.node_file, "/outputs"), received)
    np.testing.assert_array_equal(positions(run.env_file, "/outputs"), received)
    for path in (run.node_file, run.env_file):
        actions = positions(path, "/actions")
        assert actions.shape == (STEPS, 0), f"{path.name}: one empty action per step"


def test_replay_saves_both_recordings_headless(run: Run, tmp_path: Path) -> None:
    rr_chunk = pytest.importorskip(
        "rerun.chunk", reason="rerun-sdk is not installed (pip install 'fmu-bridge[viz]')"
    )
    runner = CliRunner()
    for source in (run.node_file, run.env_file):
        target = tmp_path / f"{source.stem}.rrd"
        result = runner.invoke(app, ["replay", str(source), "--save", str(target)])
        assert result.exit_code == 0, result.output + repr(result.exception)
        heights = [
            v[0]
            for chunk in rr_chunk.RrdReader(target).stream().collect().stream()
            if chunk.entity_path == "/outputs/h" and not chunk.is_static
            for batch in [chunk.to_record_batch()]
            if "Scalars:scalars" in batch.schema.names
            for v in batch.column("Scalars:scalars").to_pylist()
        ]
        assert sorted(heights) == sorted(np.array(run.outputs)[:, 0].tolist()), source.name
