"""The slow plant (``models/slow_plant``) through the agents' paths: SB3 training with subprocess
workers, ``evaluate`` with worker processes, and a deployed agent (``fmu-bridge agent run``) on a
lockstep node over Zenoh, with no setting for its slowness."""

from __future__ import annotations

import functools
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from agents.deploy import DeploySettings
from agents.deploy_io import AgentNode
from agents.evaluate import evaluate
from agents.train import train
from bridge.net import protocol as proto
from bridge.net.remote import describe_nodes
from tests.conftest import Loopback, node_process, wait_until
from tests.plant.test_slow_plant import lag
from tests.slow_plant import slow_experiment


@pytest.mark.slow  # trains (worker processes, a few seconds of slow steps)
@pytest.mark.integration
def test_sb3_trains_on_slow_plants_in_worker_processes(tmp_path: Path) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.2, init_delay_s=1.0, duration_s=0.4)
    overrides = {
        "timesteps": 16,
        "n_envs": 2,
        "vec": "subproc",
        "eval_every": 100_000,
        "hyperparams": {"n_steps": 8, "batch_size": 8, "n_epochs": 1},
    }
    result = train(path, overrides=overrides, run_dir=tmp_path / "run", progress=False)
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["status"] == "done" and result.timesteps == 16, info


@pytest.mark.integration  # worker processes
def test_evaluate_with_workers_runs_slow_plant_episodes(tmp_path: Path) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.1, init_delay_s=0.5, duration_s=0.3)
    result = evaluate(["zero"], path, episodes=4, workers=2)
    assert [row["episode"] for row in result.rows] == [0, 1, 2, 3]
    assert all(row["length"] == 3 and row["reason"] == "time" for row in result.rows), result.rows


HOLD = """\
evaluation:
  baselines:
    hold: {type: pid, output: x, reference: x, input: u, kp: 0.0, feedforward: 0.5}
"""
PARAMETERS = {"step_delay_s": 1.0, "init_delay_s": 2.0, "tau": 0.5}


def _stepped(frames: list[proto.Frame], episode: int, step: int) -> bool:
    return any(f.episode == episode and f.step >= step for f in frames)


@pytest.mark.integration  # a node process, Zenoh on 127.0.0.1
def test_a_deployed_agent_waits_for_a_slow_lockstep_plant_without_missing_observations(
    loopback: Loopback, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # 1 s a step and 2 s to initialise, against the agent's default --timeout of 0.5 s
    path = slow_experiment(tmp_path, step_delay_s=1.0, init_delay_s=2.0, duration_s=10.0, tail=HOLD)
    settings = DeploySettings(node="slow", prefix=loopback.prefix, runtime="baseline")
    keys = proto.Keys(loopback.prefix, "slow")
    frames: list[proto.Frame] = []
    with node_process(path, "slow", loopback), caplog.at_level(logging.WARNING, logger="agents.deploy"):
        agent = AgentNode(Path("hold"), path, settings, session=loopback.session)
        sub = loopback.session.declare_subscriber(  # type: ignore[attr-defined]
            keys.outputs, lambda s: frames.append(proto.decode(s.payload.to_bytes()))
        )
        try:
            for episode in (1, 2):  # the second reset initialises the FMU again while the agent waits
                request = {"episode": episode, "values": PARAMETERS}  # a bare reset keeps the FMU's defaults
                for _ in loopback.session.get(keys.reset, payload=proto.encode_json(request)):  # type: ignore[attr-defined]
                    pass
                stepped = functools.partial(_stepped, frames, episode, 3)
                wait_until(stepped, 120, f"three agent-driven steps of episode {episode}")
            node = describe_nodes(loopback.session, ["slow"], prefix=loopback.prefix, timeout_s=10)[0]
            late_after_s = agent.agent.late_after_s()
        finally:
            stats = agent.agent.stats.summary()
            agent.close()
            sub.undeclare()
    first = [f for f in frames if f.episode == 1 and f.kind == proto.OUTPUTS][:4]
    assert [f.step for f in first] == [0, 1, 2, 3]
    np.testing.assert_allclose([f.values[0] for f in first], lag(first[0].values[0], 0.5, 3), atol=1e-6)
    assert stats["missing_events"] == 0, stats
    assert [r.getMessage() for r in caplog.records if r.name == "agents.deploy"] == []
    # no action sent twice for one step; at most the one in flight when the second reset came is stale
    counters = node["counters"]
    assert "duplicate" not in counters and counters.get("rejected_stale", 0) <= 1, counters
    assert not [k for k in counters if k.startswith("rejected") and k != "rejected_stale"], counters
    assert late_after_s >= 4 * 1.0  # the measured step, with its margin
