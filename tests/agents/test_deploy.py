"""Deployed agents: the same actions as model.predict, closed loops over Zenoh and the ROS 2 view,
missing-observation rules, and the CLI as a real subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
from agents.deploy_io import AgentNode
from agents.policies import Sb3Policy
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.remote import describe_nodes
from tests.conftest import Loopback, node_process, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]  # training takes minutes when busy
CARTPOLE = example_experiment("cartpole_balance")


def test_deployed_agent_acts_exactly_like_model_predict(balancer: Path) -> None:
    policy = Sb3Policy(balancer)
    experiment, _ = deployment_experiment(balancer, None)
    sent: list[list[float]] = []
    agent = DeployedAgent(
        policy,
        experiment,
        model_info_for(experiment, balancer, None),
        DeploySettings(),
        lambda inputs, step: sent.append(inputs),
    )
    try:
        with FmuEnv(CARTPOLE) as env:
            obs, info = env.reset(seed=4)
            for step in range(200):
                expected_action, _ = policy.model.predict(obs, deterministic=True)
                inputs = agent.observe(info["outputs"].tolist(), episode=1, step=step)
                assert inputs == [10.0 if int(expected_action) == 1 else -10.0]
                obs, _, terminated, _, info = env.step(expected_action)
                assert not terminated
        assert len(sent) == 200 and agent.stats.summary()["latency_median_us"] > 0
    finally:
        agent.close()


def outputs_of(net: Loopback, node: str) -> tuple[list[proto.Frame], Any]:
    frames: list[proto.Frame] = []
    sub = net.session.declare_subscriber(  # type: ignore[attr-defined]
        proto.Keys(net.prefix, node).outputs, lambda s: frames.append(proto.decode(s.payload.to_bytes()))
    )
    return frames, sub


def closed_loop(
    balancer: Path, net: Loopback, transport: str, mode: str, samples: int
) -> tuple[list[proto.Frame], dict[str, Any], dict[str, Any]]:
    """The agent against a node for ``samples`` samples of episode 9; its frames, agent and node stats."""
    extra = ["--mode", mode, *(["--rate", "4"] if mode == "realtime" else []), "--ros"]
    with node_process(CARTPOLE, "plant", net, *extra):
        # In lockstep nothing is late by design: no missing-observation actions.
        timeout = 60.0 if mode == "lockstep" else 0.5
        settings = DeploySettings(transport=transport, node="plant", prefix=net.prefix, timeout_s=timeout)  # type: ignore[arg-type]
        agent = AgentNode(balancer, None, settings, session=net.session)
        frames, sub = outputs_of(net, "plant")
        try:
            for _ in net.session.get(
                proto.Keys(net.prefix, "plant").reset,  # type: ignore[attr-defined]
                payload=proto.encode_json({"episode": 9, "values": {"theta0": 0.04}}),
            ):
                pass
            # the samples wanted, and in real time (which runs on) a few more; a lockstep episode
            # ends after its 500 samples, so asking more of it waited for the deadline
            wanted = samples + (20 if mode == "realtime" else 0)
            deadline = time.monotonic() + 120
            while len([f for f in frames if f.episode == 9]) < wanted and time.monotonic() < deadline:
                time.sleep(0.05)
            node = describe_nodes(net.session, ["plant"], prefix=net.prefix, timeout_s=10)[0]  # type: ignore[arg-type]
        finally:
            stats = agent.agent.stats.summary()
            agent.close()
            sub.undeclare()
    episode = [f for f in frames if f.episode == 9 and f.kind == proto.OUTPUTS][:samples]
    return episode, stats, node


@pytest.mark.parametrize("transport", ["zenoh", "ros2"])
def test_closed_loop_keeps_the_pole_up_for_a_whole_episode(
    balancer: Path, loopback: Loopback, transport: str
) -> None:
    """Correctness in lockstep: the node waits for every action, so a busy machine cannot change it."""
    episode, stats, _ = closed_loop(balancer, loopback, transport, "lockstep", 500)
    theta = np.array([f.values[2] for f in episode])
    x = np.array([f.values[0] for f in episode])
    assert len(episode) == 500 and [f.step for f in episode] == list(range(500))
    assert np.abs(theta).max() < 0.2094 and np.abs(x).max() < 2.4  # inside the task's bounds throughout
    assert stats["actions"] >= 499


@pytest.mark.parametrize("transport", ["zenoh", "ros2"])
def test_closed_loop_in_real_time_reports_its_deadline_misses(
    balancer: Path, loopback: Loopback, transport: str, record_property: Any
) -> None:
    """Real time on a shared machine: what must hold is asserted, what depends on load is measured."""
    episode, stats, node = closed_loop(balancer, loopback, transport, "realtime", 200)
    steps = [f.step for f in episode]
    assert steps == list(range(steps[0], steps[0] + len(steps)))  # every sample published, in order
    assert len(episode) == 200 and stats["actions"] > 0
    misses = {
        "node_overruns": node["counters"].get("overruns", 0),
        "missing_observation_events": stats.get("missing_events", 0),
        "latency_median_us": stats["latency_median_us"],
        "max_abs_theta": float(np.abs([f.values[2] for f in episode]).max()),
    }
    for key, value in misses.items():
        record_property(key, value)  # in the JUnit report: deadline misses are reported, not asserted


def test_missing_observations_hold_or_go_safe(balancer: Path) -> None:
    policy = Sb3Policy(balancer)
    experiment, _ = deployment_experiment(balancer, None)
    info = model_info_for(experiment, balancer, None)
    for rule, expected in (("hold", [10.0]), ("safe", [2.5])):
        sent: list[list[float]] = []
        settings = DeploySettings(missing=rule, safe_inputs=[2.5], timeout_s=0.1)  # type: ignore[arg-type]
        agent = DeployedAgent(
            policy, experiment, info, settings, lambda inputs, step, sent=sent: sent.append(inputs)
        )
        try:
            agent._last_inputs = [10.0]  # as if the last observation led to a push right
            agent._last_time = time.monotonic()
            wait_until(  # no observations at all
                lambda a=agent, s=sent: a.stats.missing_events >= 2 and len(s) >= 2,
                30.0,
                f"the {rule!r} rule acts",
            )
        finally:
            agent.close()
        assert agent.stats.missing_events >= 2 and sent and all(s == expected for s in sent)


def test_agent_run_command_as_a_subprocess(balancer: Path, loopback: Loopback) -> None:
    with node_process(CARTPOLE, "plant", loopback, "--mode", "realtime", "--rate", "2"):
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "bridge.cli",
                "agent",
                "run",
                str(balancer),
                "--node",
                "plant",
                "--prefix",
                loopback.prefix,
                "--connect",
                loopback.endpoint,
                "--duration",
                "2",
            ],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
            env={**os.environ, "COLUMNS": "200"},
        )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "inference latency median" in result.stdout and " 0 missing-observation events" in result.stdout


def test_closed_loop_launcher_runs_node_agent_and_recorder(balancer: Path, tmp_path: Path) -> None:
    from tests.conftest import free_port

    script = Path(__file__).resolve().parents[2] / "launch_scripts" / "closed_loop.py"
    recording = tmp_path / "loop.mcap"
    result = subprocess.run(
        [
            sys.executable,
            str(script),
            str(balancer),
            "--rate",
            "4",
            "--duration",
            "4",
            "--record",
            str(recording),
            "--port",
            str(free_port()),
        ],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "inference latency median" in " ".join(result.stdout.split())  # rich wraps long lines
    assert recording.is_file() and recording.stat().st_size > 1000


def test_ros2_launch_file_describes_both_nodes() -> None:
    launch = pytest.importorskip("launch", reason="the ROS 2 launch system comes with a ROS 2 install")
    import runpy

    path = Path(__file__).resolve().parents[2] / "launch_scripts" / "fmu_agent.launch.py"
    description = runpy.run_path(str(path))["generate_launch_description"]()
    assert isinstance(description, launch.LaunchDescription)
