"""Command-line defects of training and deployment: resume exactly as the README writes it, one safe
value per action input, latency statistics in bounded memory, the Zenoh session mode."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from agents.cli import agent_settings, safe_inputs
from agents.deploy import DeployedAgent, Stats, deployment_experiment, model_info_for
from agents.latency import LatencyWindow
from agents.train import train
from bridge.cli.main import _load_plugins, app
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment
from bridge.net.transport import session_mode
from tests.conftest import wait_until

CARTPOLE = example_experiment("cartpole_balance")
MOTOR = example_experiment("dcmotor_tracking")


@pytest.mark.slow
def test_train_resume_from_the_command_line_keeps_the_stored_settings(tmp_path: Path) -> None:
    run = tmp_path / "run"
    overrides = {"algo": "A2C", "timesteps": 64, "n_envs": 1, "hyperparams": {"n_steps": 8}}
    first = train(CARTPOLE, overrides=overrides, run_dir=run, progress=False)
    _load_plugins()
    out = CliRunner().invoke(app, ["train", "--resume", str(run), "--timesteps", "64", "--no-progress"])
    assert out.exit_code == 0, out.output + repr(out.exception)
    info = json.loads((run / "run.json").read_text())
    # the experiment file says PPO with 8 envs: the run's A2C with 1 env must survive the resume
    assert info["algo"] == "A2C" and info["settings"]["n_envs"] == 1
    assert info["timesteps"] >= first.timesteps + 64 and info["resumed"][0]["at"] == first.timesteps


def test_resume_of_a_directory_that_is_no_run_says_so(tmp_path: Path) -> None:
    _load_plugins()
    out = CliRunner().invoke(app, ["train", "--resume", str(tmp_path), "--no-progress"])
    assert out.exit_code != 0 and "not a run directory" in str(out.exception)
    out = CliRunner().invoke(app, ["train", "--no-progress"])
    assert out.exit_code != 0 and "--resume" in str(out.exception)


def test_safe_values_cover_every_action_input() -> None:
    assert safe_inputs(None, 2) == [0.0, 0.0]
    assert safe_inputs([1.5], 3) == [1.5, 1.5, 1.5]
    assert safe_inputs([1.0, -2.0], 2) == [1.0, -2.0]
    with pytest.raises(ConfigError, match="2 values for 3 action inputs"):
        safe_inputs([1.0, 2.0], 3)


TWO_INPUTS = """
name: two-inputs
model: {fmu: example:dcmotor, step_size: 0.01, sampling_time: 0.01, episode_duration: 1.0}
actions:
  inputs: [voltage, load_torque]
  type: continuous
  low: {load_torque: -0.1}
  high: {load_torque: 0.1}
observations: {outputs: [omega, current]}
reward: {terms: [{alive: 1.0}]}
"""


def two_input_experiment(tmp_path: Path) -> Path:
    path = tmp_path / "two_inputs.yaml"
    path.write_text(TWO_INPUTS)
    return path


class Zero:
    name = "zero"

    def reset(self, task: Any, seed: int | None) -> None:
        pass

    def act(self, obs: Any, signals: Any) -> Any:
        return np.zeros(2, dtype=np.float32)


def test_missing_safe_publishes_a_full_vector_for_two_inputs(tmp_path: Path) -> None:
    config = two_input_experiment(tmp_path)
    settings = agent_settings(tmp_path, config, "zenoh", "safe", [1.5], "torch", timeout_s=0.1)
    assert settings.safe_inputs == [1.5, 1.5]
    experiment, _ = deployment_experiment(tmp_path, config)
    sent: list[list[float]] = []
    agent = DeployedAgent(
        Zero(), experiment, model_info_for(experiment, tmp_path, None), settings,
        lambda inputs, step: sent.append(list(inputs)),
    )  # fmt: skip
    try:
        agent._last_inputs = [3.0, 0.05]
        agent._last_time = time.monotonic()
        wait_until(lambda: len(sent) >= 2, 30.0, "the watchdog sends the safe inputs")
    finally:
        agent.close()
    assert sent and all(s[:2] == [1.5, 1.5] for s in sent)


def test_close_waits_for_a_publish_under_way_and_later_observations_publish_nothing(
    tmp_path: Path,
) -> None:
    """A transport closes right after ``close()``: a publish may not run on into it, nor start."""
    import threading

    config = two_input_experiment(tmp_path)
    experiment, _ = deployment_experiment(tmp_path, config)
    settings = agent_settings(tmp_path, config, "zenoh", "hold", None, "torch", timeout_s=60.0)
    entered, events = threading.Event(), []

    def slow_publish(inputs: list[float], step: int) -> None:
        entered.set()
        time.sleep(0.3)
        events.append("published")

    agent = DeployedAgent(
        Zero(), experiment, model_info_for(experiment, tmp_path, None), settings, slow_publish
    )
    worker = threading.Thread(target=agent.observe, args=([10.0, 0.1],), kwargs={"step": 0})
    worker.start()
    assert entered.wait(10.0)
    agent.close()
    events.append("closed")
    worker.join(10.0)
    assert events == ["published", "closed"]
    assert agent.observe([10.0, 0.1], step=1) == [] and agent.stats.actions == 1


def test_latency_statistics_stay_bounded() -> None:
    window = LatencyWindow(capacity=1000)
    for k in range(10_000):
        window.append(1e-6 * (k % 100))
    assert len(window) == 1000 and window.count == 10_000 and window.window().nbytes == 8000
    assert window.quantile(0.5) == pytest.approx(49e-6) and window.quantile(0.99) == pytest.approx(98e-6)
    stats = Stats()
    for _ in range(stats.latencies_s.capacity + 10):
        stats.latencies_s.append(2e-6)
    assert len(stats.latencies_s) == stats.latencies_s.capacity
    assert stats.summary()["latency_median_us"] == pytest.approx(2.0)
    assert np.isnan(Stats().summary()["latency_p99_us"])


def test_zenoh_mode_is_client_when_only_connecting() -> None:
    router, here = ("tcp/10.0.0.1:7447",), ("tcp/0.0.0.0:7448",)
    assert session_mode(None, (), router, None) == "client"  # only connects: to a router
    assert session_mode(None, (), (), None) is None  # Zenoh's default: a peer finding peers
    assert session_mode(None, here, router, None) is None  # listens too: a peer
    assert session_mode(None, (), router, Path("z.json5")) is None  # the file says its mode
    assert session_mode("peer", (), router, None) == "peer"
    assert session_mode("client", (), router, Path("z.json5")) == "client"
    with pytest.raises(Exception, match="client or peer"):
        session_mode("router", (), (), None)
    with pytest.raises(Exception, match="a client does not accept connections"):
        session_mode("client", here, router, None)
