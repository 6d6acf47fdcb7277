"""An RLlib-trained policy goes through the same ONNX path as SB3 agents: ``train --engine rllib``
(PPO and SAC, short real trainings on the cart-pole FMU with a continuous force) writes
``policy.onnx`` into the run folder; its actions equal the actions of the trained RLlib module
computed by RLlib's own classes (inference forward pass, the module's action distribution made
deterministic, ``unsquash_action`` onto the action space) on observations recorded from episodes;
``evaluate RUN`` and ``agent check --runtime onnx`` work on the run as they do on an SB3 run."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

pytest.importorskip("ray.rllib")

from agents.rllib_train import RllibResult, train_rllib
from bridge.experiment.examples import example_experiment

TRAINING = {
    "PPO": "  algo: PPO\n  timesteps: 256\n  n_envs: 4\n  seed: 5\n"
    "  hyperparams: {n_steps: 32, batch_size: 64, n_epochs: 2, learning_rate: 0.001,"
    " policy_kwargs: {net_arch: [16, 16]}}\n",
    "SAC": "  algo: SAC\n  timesteps: 300\n  n_envs: 2\n  seed: 5\n"
    "  hyperparams: {learning_rate: 0.001, buffer_size: 5000, learning_starts: 100, batch_size: 32,"
    " tau: 0.01, gamma: 0.98, ent_coef: auto_0.5, policy_kwargs: {net_arch: [16, 16]}}\n",
}


def experiment(tmp_path: Path, algo: str) -> Path:
    """The example without its observation noise (a recording then replays exactly: deployment
    leaves training-time noise out), with a short training section."""
    data = yaml.safe_load(example_experiment("cartpole_continuous").read_text())
    del data["noise"]
    path = tmp_path / "cartpole_continuous.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False) + "training:\n" + TRAINING[algo])
    return path


RESULTS: dict[str, list[dict[str, Any]]] = {}


@pytest.fixture(scope="module", params=["PPO", "SAC"])
def trained(ray_cluster: Any, request: Any, tmp_path_factory: pytest.TempPathFactory) -> RllibResult:
    folder = tmp_path_factory.mktemp(f"rllib_{request.param.lower()}")
    results = RESULTS.setdefault(request.param, [])
    return train_rllib(
        experiment(folder, request.param),
        run_dir=folder / "run",
        runners=0,
        on_iteration=lambda algo, result: results.append(result),
    )


def test_training_samples_its_timesteps_and_updates_the_policy(trained: RllibResult) -> None:
    import json

    info = json.loads((trained.run_dir / "run.json").read_text())
    results = RESULTS[info["algo"]]
    assert info["status"] == "done" and info["engine"] == "rllib"
    assert trained.timesteps >= {"PPO": 256, "SAC": 300}[info["algo"]]  # the sections' timesteps
    learner = results[-1]["learners"]["default_policy"]
    assert learner["num_module_steps_trained_lifetime"] > 0, learner
    assert info["algo"] in ("PPO", "SAC") and len(results) == trained.iterations


def recorded_observations(run: Path) -> np.ndarray:
    """The observation vectors of two episodes of the exported policy acting on the FMU, and the same
    vectors scaled up (states the short training never saw: a wider range of actions)."""
    from agents.runtime import OnnxPolicy
    from bridge.env.fmu_env import FmuEnv

    policy = OnnxPolicy(run)
    env = FmuEnv(run / "experiment.yaml")
    observations = []
    try:
        for seed in (0, 1):
            obs, _ = env.reset(seed=seed)
            for _ in range(60):
                observations.append(obs)
                action, _ = policy.predict(obs[None])
                obs, _, terminated, truncated, _ = env.step(action[0])
                if terminated or truncated:
                    break
    finally:
        env.close()
    recorded = np.asarray(observations, dtype=np.float32)
    return np.concatenate([recorded, 8.0 * recorded])


def rllib_actions(checkpoint: Path, observations: np.ndarray) -> np.ndarray:
    """What RLlib's env runner does with ``explore=False``, with RLlib's own classes."""
    import torch
    from ray.rllib.core.columns import Columns
    from ray.rllib.core.rl_module.rl_module import RLModule
    from ray.rllib.utils.spaces.space_utils import unsquash_action

    module = RLModule.from_checkpoint(str(checkpoint / "learner_group/learner/rl_module/default_policy"))
    with torch.no_grad():
        out = module.forward_inference({Columns.OBS: torch.as_tensor(observations)})
    dist = module.get_inference_action_dist_cls().from_logits(out[Columns.ACTION_DIST_INPUTS])
    actions = dist.to_deterministic().sample().numpy()
    return np.asarray(unsquash_action(actions, module.action_space))


def test_the_onnx_policy_acts_as_the_rllib_module(trained: RllibResult) -> None:
    from agents.runtime import OnnxPolicy

    run = trained.run_dir
    assert trained.onnx == run / "policy.onnx" and trained.onnx.is_file()
    observations = recorded_observations(run)
    expected = rllib_actions(trained.checkpoint, observations)
    actions, inputs = OnnxPolicy(run).predict(observations)
    assert expected.shape == actions.shape == (len(observations), 1)
    assert np.ptp(expected) > 1e-3  # the policy's action depends on the observation
    np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(inputs[:, 0], 10.0 * np.clip(expected[:, 0], -1, 1), atol=1e-5)


def test_evaluate_and_agent_check_work_on_the_rllib_run(trained: RllibResult, tmp_path: Path) -> None:
    from agents.evaluate import evaluate

    run = trained.run_dir
    result = evaluate([str(run)], run / "experiment.yaml", episodes=2, record_dir=tmp_path / "rec")
    assert [r["agent"] for r in result.rows] == [run.name] * 2 and len(result.recordings) == 1
    assert all(r["length"] > 0 for r in result.rows)
    recording = result.recordings[0]
    check = agent_check(run, recording, "onnx")
    assert check.returncode == 0 and "check passed" in check.stdout, check.stdout + check.stderr
    assert re.search(r"largest action difference\s+result: 0 ", check.stdout), check.stdout
    torch_runtime = agent_check(run, recording, "torch")  # no SB3 model: refused, with the way out
    assert torch_runtime.returncode != 0 and "--runtime onnx" in torch_runtime.stdout + torch_runtime.stderr


def agent_check(run: Path, recording: Path, runtime: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "bridge.cli", "agent", "check", str(run), "--recording", str(recording)]
    return subprocess.run(
        [*cmd, "--runtime", runtime],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "COLUMNS": "200"},
    )


def test_agent_run_deploys_the_rllib_run_without_torch(
    trained: RllibResult, loopback: Any, tmp_path: Path
) -> None:
    """``agent run ROBOT --runtime onnx`` (torch and stable-baselines3 unimportable in its process),
    given only what a robot gets from the run (its experiment, model snapshot and ONNX policy),
    closes the loop with a real cart-pole node in lockstep on a Zenoh router at 127.0.0.1."""
    import shutil

    from tests.agents.test_deploy_torch_free import SUMMARY, agent_process, drive_one_episode
    from tests.conftest import node_process

    run = tmp_path / "robot"
    run.mkdir()
    for name in ("experiment.yaml", "model.json", "policy.onnx"):
        shutil.copy2(trained.run_dir / name, run / name)
    samples = 40
    log = tmp_path / "blocked.txt"
    with (
        node_process(run / "experiment.yaml", "plant", loopback, "--mode", "lockstep"),
        agent_process(run, loopback, "zenoh", log) as agent,
    ):
        episode = drive_one_episode(loopback, samples)
    output = agent.stdout.read()
    agent.stdout.close()
    assert not log.exists(), f"the deployed agent tried to import torch:\n{log.read_text()}"
    assert agent.returncode == 0, output[-3000:]
    assert [f.step for f in episode] == list(range(samples))  # lockstep: each step waited for its action
    found = SUMMARY.search(" ".join(output.split()))
    assert found is not None and int(found.group(2)) >= samples - 1, output[-3000:]


def test_the_run_exports_again_where_ray_cannot_be_imported(trained: RllibResult, tmp_path: Path) -> None:
    """``agent export onnx`` reads ``rllib_policy.npz``: no Ray needed after training."""
    from agents.runtime import OnnxPolicy

    out = tmp_path / "again.onnx"
    code = (
        "import sys; sys.modules['ray'] = None  # import ray fails from here on\n"
        "from bridge.cli.main import main\n"
        f"sys.argv = ['fmu-bridge', 'agent', 'export', 'onnx', {str(trained.run_dir)!r}, "
        f"'-o', {str(out)!r}]\n"
        "main()\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 0 and out.is_file(), result.stdout + result.stderr
    observations = recorded_observations(trained.run_dir)
    again, _ = OnnxPolicy(out).predict(observations)
    first, _ = OnnxPolicy(trained.run_dir).predict(observations)
    np.testing.assert_array_equal(again, first)
