"""A baseline deployed like a trained agent (``agent run --runtime baseline``): the deployed agent's
inputs are the baseline's, step by step, and it keeps the cart-pole up for a whole episode."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
from agents.deploy_io import AgentNode
from agents.policies import load_policy, make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from tests.conftest import Loopback, node_process

CARTPOLE = example_experiment("cartpole_continuous")


def test_deployed_lqr_acts_like_the_evaluated_one_and_balances() -> None:
    experiment, _ = deployment_experiment(Path("lqr"), CARTPOLE)
    policy = load_policy(Path("lqr"), "baseline", experiment)
    sent: list[list[float]] = []
    agent = DeployedAgent(
        policy, experiment, model_info_for(experiment, CARTPOLE.parent, None),
        DeploySettings(runtime="baseline"), lambda inputs, step: sent.append(inputs),
    )  # fmt: skip
    reference = make_policy("lqr", {"lqr": experiment.evaluation.baselines["lqr"].settings()})
    env = FmuEnv(experiment)
    try:
        obs, info = env.reset(seed=2)
        reference.reset(env.task, 2)
        for step in range(500):
            expected = reference.act(obs, env.task.signal_dict())
            inputs = agent.observe(info["outputs"].tolist(), episode=1, step=step)
            assert inputs[0] == pytest.approx(float(env.task.action_mapping.half[0] * expected[0]), abs=1e-5)
            obs, _, terminated, truncated, info = env.step(expected)
            assert not terminated
        assert truncated and len(sent) == 500
        assert abs(float(info["outputs"][2])) < 0.05  # theta: the pole is up at the end
    finally:
        agent.close()
        env.close()


def test_baseline_runtime_needs_a_baseline_of_the_experiment() -> None:
    experiment, _ = deployment_experiment(Path("lqr"), CARTPOLE)
    with pytest.raises(ConfigError, match=r"not in evaluation\.baselines"):
        load_policy(Path("mpc"), "baseline", experiment)


def test_lqr_over_zenoh_keeps_a_cartpole_node_up_for_a_whole_episode(loopback: Loopback) -> None:
    """The deployed path of ``agent run lqr --runtime baseline``: a real node in lockstep on loopback."""
    settings = DeploySettings(
        transport="zenoh", node="plant", prefix=loopback.prefix, timeout_s=60.0, runtime="baseline"
    )
    with node_process(CARTPOLE, "plant", loopback, "--mode", "lockstep"):
        agent = AgentNode(Path("lqr"), CARTPOLE, settings, session=loopback.session)
        frames: list[proto.Frame] = []
        sub = loopback.session.declare_subscriber(  # type: ignore[attr-defined]
            proto.Keys(loopback.prefix, "plant").outputs,
            lambda s: frames.append(proto.decode(s.payload.to_bytes())),
        )
        try:
            for _ in loopback.session.get(  # type: ignore[attr-defined]
                proto.Keys(loopback.prefix, "plant").reset,
                payload=proto.encode_json({"episode": 3, "values": {"theta0": 0.05}}),
            ):
                pass
            deadline = time.monotonic() + 120
            while len([f for f in frames if f.episode == 3]) < 500 and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            agent.close()
            sub.undeclare()
    episode = [f for f in frames if f.episode == 3 and f.kind == proto.OUTPUTS][:500]
    assert len(episode) == 500 and [f.step for f in episode] == list(range(500))
    theta = np.array([f.values[2] for f in episode])
    assert np.abs(theta).max() < 0.06  # from 0.05 rad the pole is brought up and kept there
    assert np.abs(theta[-100:]).max() < 0.01


def test_a_deployed_baseline_needs_no_torch() -> None:
    """In a process where importing torch or stable-baselines3 fails, the lqr designs and acts."""
    blocker = Path(__file__).resolve().parents[1] / "agents" / "torch_free"
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from agents.deploy import deployment_experiment\n"
        "from agents.policies import load_policy\n"
        "from bridge.env.fmu_env import FmuEnv\n"
        f"experiment, _ = deployment_experiment(Path('lqr'), Path({str(CARTPOLE)!r}))\n"
        "policy = load_policy(Path('lqr'), 'baseline', experiment)\n"
        "env = FmuEnv(experiment)\n"
        "obs, _ = env.reset(seed=0)\n"
        "policy.reset(env.task, 0)\n"
        "for _ in range(50):\n"
        "    obs, _, terminated, _, _ = env.step(policy.act(obs, env.task.signal_dict()))\n"
        "    assert not terminated\n"
        "print('torch' in sys.modules, 'stable_baselines3' in sys.modules)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(blocker), os.environ.get("PYTHONPATH", "")])}
    command = [sys.executable, "-c", code]
    done = subprocess.run(command, check=False, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "False False"


def test_agent_run_deploys_a_baseline_and_says_so(loopback: Loopback) -> None:
    """``agent run lqr --runtime baseline``: no checkpoint to find, the command names the baseline."""
    args = ["agent", "run", "lqr", "--config", str(CARTPOLE), "--runtime", "baseline", "--node", "plant",
            "--prefix", loopback.prefix, "--connect", loopback.endpoint, "--duration", "2"]  # fmt: skip
    with node_process(CARTPOLE, "plant", loopback, "--mode", "realtime"):
        result = subprocess.run(
            [sys.executable, "-m", "bridge.cli", *args],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
            env={**os.environ, "COLUMNS": "200"},
        )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "agent deploys baseline lqr of the experiment's evaluation.baselines" in result.stdout
    assert "inference latency median" in result.stdout


def test_missing_observations_are_told_at_the_1st_10th_100th_event(caplog: pytest.LogCaptureFixture) -> None:
    """A node gone for good: the missing rule acts at every timeout, the log says so at the 1st,
    10th, 100th... event in a row (not every timeout), and says when observations come back."""
    import logging

    experiment, _ = deployment_experiment(Path("lqr"), CARTPOLE)
    policy = load_policy(Path("lqr"), "baseline", experiment)
    sent: list[list[float]] = []
    settings = DeploySettings(runtime="baseline", timeout_s=0.02, missing="safe", safe_inputs=[0.0])
    caplog.set_level(logging.INFO, logger="agents.deploy")
    agent = DeployedAgent(
        policy, experiment, model_info_for(experiment, CARTPOLE.parent, None), settings,
        lambda inputs, step: sent.append(inputs),
    )  # fmt: skip
    try:
        agent.observe([0.0, 0.0, 0.05, 0.0])
        deadline = time.monotonic() + 120
        while agent.stats.missing_events < 25 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert agent.stats.missing_events >= 25
        agent.observe([0.0, 0.0, 0.05, 0.0], step=1)
    finally:
        agent.close()
    events = agent.stats.missing_events
    told = [r.getMessage() for r in caplog.records if "no observation for" in r.getMessage()]
    in_a_row = [m.split("(")[1].split(" ")[0] for m in told]
    assert in_a_row == [str(n) for n in (1, 10, 100, 1000) if n <= events], (events, told)
    assert sent.count([0.0]) == events  # the safe action went out at every one
    assert any("observations again after" in r.getMessage() for r in caplog.records)
