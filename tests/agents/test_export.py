"""Exported policies: the ONNX graph and the policy FMU act exactly like model.predict (with VecNormalize),
the FMU passes FMPy's validator, closes the loop with the plant FMU like the Python env does, and the
onnx runtime of the deployed agent works with torch and stable-baselines3 absent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from agents.deploy import deployment_experiment, model_info_for
from agents.export.extract import actor_modules
from agents.export.fmu_runner import FmuPolicy
from agents.export.onnx import export_onnx
from agents.export.policy_fmu import export_fmu
from agents.policies import Sb3Policy
from agents.runtime import OnnxPolicy
from agents.train import train
from bridge.cli.main import _load_plugins, app
from bridge.experiment.examples import example_experiment
from bridge.experiment.validate import timing
from bridge.task.core import Task

pytestmark = pytest.mark.slow
CONTINUOUS = example_experiment("cartpole_continuous")
DISCRETE = example_experiment("cartpole_balance")
N_OBS = 10_000
HYPERPARAMS = {
    "PPO": {"n_steps": 64, "batch_size": 64, "n_epochs": 2},
    "A2C": {"n_steps": 16},
    "SAC": {"learning_starts": 64, "batch_size": 32, "buffer_size": 2000},
    "TD3": {"learning_starts": 240, "batch_size": 32, "buffer_size": 2000},  # a few updates: not saturated
    "DQN": {"learning_starts": 64, "batch_size": 32, "buffer_size": 2000},
}
CASES = [("PPO", CONTINUOUS), ("A2C", CONTINUOUS), ("SAC", CONTINUOUS), ("TD3", CONTINUOUS)]
CASES += [("DQN", DISCRETE), ("PPO", DISCRETE)]
IDS = [f"{algo}-{path.stem}" for algo, path in CASES]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One briefly trained run per case (normalised observations: the statistics must be exported too)."""
    root = tmp_path_factory.mktemp("export")
    out = {}
    for (algo, experiment), name in zip(CASES, IDS):
        overrides = {"algo": algo, "timesteps": 256, "n_envs": 1, "normalize": True}
        overrides["hyperparams"] = HYPERPARAMS[algo]
        train(experiment, overrides=overrides, run_dir=root / name, progress=False)
        out[name] = root / name
    return out


def task_of(run: Path) -> Task:
    experiment, _ = deployment_experiment(run, None)
    info = model_info_for(experiment, run, None)
    return Task(experiment, info.variables, timing(experiment, info))


def raw_signals(n: int, seed: int) -> np.ndarray:
    """Cart-pole outputs (x, x_dot, theta, theta_dot) around and beyond their training range."""
    return np.random.default_rng(seed).normal(0.0, [1.0, 1.5, 0.15, 1.5], size=(n, 4))


def observations(task: Task, signals: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.array([task.observer.observe(task.fill_signals(s.tolist(), 0), [0.0], rng) for s in signals])


def reference(policy: Sb3Policy, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """model.predict on the batch (with VecNormalize), and for discrete actions the top-two margin."""
    import torch

    normalised = policy.normalise(obs)
    actions, _ = policy.model.predict(normalised, deterministic=True)
    algo = policy.run["algo"]
    with torch.no_grad():
        y = torch.nn.Sequential(*actor_modules(policy.model, algo))(torch.as_tensor(normalised).float())
    top2 = torch.topk(y, 2, dim=1).values if y.shape[1] > 1 else torch.zeros((len(y), 2)) + np.inf
    return actions, (top2[:, 0] - top2[:, 1]).numpy()


def assert_same_actions(actual: np.ndarray, expected: np.ndarray, margin: np.ndarray) -> None:
    if expected.dtype.kind in "iu":  # argmax: equal wherever the two best values are not a near-tie
        clear = margin > 1e-5
        assert clear.mean() > 0.99
        np.testing.assert_array_equal(actual.reshape(-1)[clear], expected.reshape(-1)[clear])
    else:
        np.testing.assert_allclose(actual.reshape(expected.shape), expected, rtol=0, atol=1e-5)
        assert np.ptp(expected) > 0.01  # the policy does not answer a constant: the test can fail


@pytest.mark.parametrize("name", IDS)
def test_onnx_actions_equal_model_predict(runs: dict[str, Path], name: str) -> None:
    run = runs[name]
    path = export_onnx(run)
    policy, onnx_policy = Sb3Policy(run), OnnxPolicy(path)
    task = task_of(run)
    obs = observations(task, raw_signals(N_OBS, 1)).astype(np.float32)
    expected, margin = reference(policy, obs)
    actions, inputs = onnx_policy.predict(obs)
    assert_same_actions(actions, expected, margin)
    physical = np.array([task.action_to_inputs(a, 0, np.random.default_rng())[:1] for a in expected[:200]])
    np.testing.assert_allclose(inputs[:200], physical, atol=1e-4)
    meta = onnx_policy.metadata
    assert meta["observation_names"] == ["x", "x_dot", "theta", "theta_dot"]
    assert meta["action_inputs"] == ["force"] and meta["units"]["force"] == "N"
    assert meta["algo"] == policy.run["algo"] and "torch" in meta["packages"]


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("name", IDS)
def test_policy_fmu_actions_equal_model_predict(runs: dict[str, Path], name: str, fmi: str) -> None:
    run = runs[name]
    policy, task = Sb3Policy(run), task_of(run)
    signals = raw_signals(N_OBS, 2)
    expected, margin = reference(policy, observations(task, signals).astype(np.float32))
    with FmuPolicy(export_fmu(run, fmi, run / f"p{fmi}.fmu")) as fmu:
        assert fmu.input_names == ["x", "x_dot", "theta", "theta_dot"]  # the signals, not scaled values
        force = np.array([fmu.act(s)[0] for s in signals])
    if expected.dtype.kind in "iu":
        levels = np.array(task.experiment.actions.levels["force"])
        actions = np.array([int(np.argmin(np.abs(levels - f))) for f in force])
        assert np.isin(force, levels).all()
    else:
        actions = force / 10.0  # force = 10 N * clip(action, -1, 1)
        expected = np.clip(expected, -1.0, 1.0)
    assert_same_actions(actions, expected, margin)


def test_policy_fmus_pass_fmpys_validator_and_inspect(runs: dict[str, Path]) -> None:
    from fmpy.validation import validate_fmu

    _load_plugins()
    for fmi in ("2", "3"):
        out = CliRunner().invoke(
            app, ["agent", "export", "fmu", str(runs["SAC-cartpole_continuous"]), "--fmi", fmi]
        )
        assert out.exit_code == 0, out.output
        path = runs["SAC-cartpole_continuous"] / f"policy-fmi{fmi}.fmu"
        assert validate_fmu(str(path)) == []
        shown = CliRunner().invoke(app, ["inspect", str(path), "--json"])
        assert shown.exit_code == 0, shown.output
        assert "theta_dot" in shown.output and "force" in shown.output
    bad = CliRunner().invoke(
        app, ["agent", "export", "fmu", str(runs["SAC-cartpole_continuous"]), "--fmi", "1"]
    )
    assert bad.exit_code != 0 and "FMI 2 or 3" in str(bad.exception) + bad.output


def test_plant_fmu_and_policy_fmu_reproduce_the_python_closed_loop(runs: dict[str, Path]) -> None:
    from bridge.env.fmu_env import FmuEnv
    from bridge.fmu import Model

    run = runs["PPO-cartpole_continuous"]
    policy = Sb3Policy(run)
    experiment, _ = deployment_experiment(run, None)  # noise-free, as deployed
    python_loop, drawn = [], {}
    with FmuEnv(experiment) as env:
        obs, info = env.reset(seed=11)
        drawn = info["drawn"]
        for _ in range(500):
            python_loop.append(info["outputs"].copy())
            obs, _, terminated, truncated, info = env.step(policy.act(obs, {}))
            if terminated or truncated:
                break
        fmu_path, step_s = env.plant.fmu_path, env.timing.sampling_time_s
    fmu_loop = []
    with (
        FmuPolicy(export_fmu(run, "3", run / "loop.fmu")) as agent,
        Model(fmu_path, step_size_s=step_s) as plant,
    ):
        plant.initialize(drawn)
        outputs = plant.signals(["x", "x_dot", "theta", "theta_dot"])
        force = plant.signals(["force"], writable=True)
        for _ in python_loop:
            y = outputs.read()
            fmu_loop.append(y)
            force.write(agent.act(y))
            plant.advance()
            agent.step()
    assert len(python_loop) > 20
    np.testing.assert_allclose(np.array(fmu_loop), np.array(python_loop), rtol=0, atol=1e-5)


TORCH_FREE = """
import json, sys
sys.modules["torch"] = None
sys.modules["stable_baselines3"] = None
from pathlib import Path
from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
from agents.policies import load_policy
run = Path(sys.argv[1])
experiment, _ = deployment_experiment(run, None)
sent = []
runtime = sys.argv[3]
agent = DeployedAgent(load_policy(run, runtime), experiment, model_info_for(experiment, run, None),
                      DeploySettings(runtime=runtime), lambda inputs, step: sent.append(list(inputs)))
for step, outputs in enumerate(json.loads(sys.argv[2])):
    agent.observe(outputs, episode=1, step=step)
agent.close()
loaded = [m for m, v in sys.modules.items() if v is not None and m.startswith(("torch", "stable_"))]
print(json.dumps({"sent": sent, "torch": loaded}))
"""


@pytest.mark.parametrize(
    ("runtime", "name"),
    [
        ("onnx", "SAC-cartpole_continuous"),
        ("fmu", "SAC-cartpole_continuous"),
        ("fmu", "PPO-cartpole_balance"),
    ],
)
def test_deployed_runtime_acts_as_torch_without_torch(runs: dict[str, Path], runtime: str, name: str) -> None:
    """``agent run --runtime onnx|fmu``: the deployed agent's physical inputs equal those of the
    torch runtime on the same outputs, in a process where torch cannot be imported."""
    from agents.deploy import DeployedAgent, DeploySettings

    run = runs[name]
    export_onnx(run) if runtime == "onnx" else export_fmu(run, "2")
    outputs = raw_signals(50, 3).tolist()
    result = subprocess.run(
        [sys.executable, "-c", TORCH_FREE, str(run), json.dumps(outputs), runtime],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    answer: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    assert answer["torch"] == []
    experiment, _ = deployment_experiment(run, None)
    expected: list[list[float]] = []
    agent = DeployedAgent(
        Sb3Policy(run), experiment, model_info_for(experiment, run, None), DeploySettings(),
        lambda inputs, step: expected.append(list(inputs)),
    )  # fmt: skip
    for step, out in enumerate(outputs):
        agent.observe(out, episode=1, step=step)
    agent.close()
    assert len(answer["sent"]) == 50
    np.testing.assert_allclose(answer["sent"], expected, rtol=0, atol=1e-4)  # 10 N * 1e-5
    assert np.ptp(np.array(expected)) > 0.1  # the actions vary: a constant answer would fail


def test_onnx_policy_refuses_a_mismatching_experiment(runs: dict[str, Path]) -> None:
    from bridge.errors import ConfigError

    path = export_onnx(runs["DQN-cartpole_balance"])
    dcmotor = example_experiment("dcmotor_tracking")
    from bridge.experiment.config import load_experiment
    from bridge.experiment.validate import resolve_fmu
    from bridge.fmu import read_model_info

    experiment = load_experiment(dcmotor)
    info = read_model_info(resolve_fmu(experiment))
    task = Task(experiment, info.variables, timing(experiment, info))
    with pytest.raises(ConfigError, match="exported for 4 observations"):
        OnnxPolicy(path).reset(task, None)
    with pytest.raises(ConfigError, match="export onnx"):
        OnnxPolicy(path.parent / "checkpoints")


def test_policy_fmu_runtime_refuses_a_mismatching_experiment(runs: dict[str, Path]) -> None:
    from agents.export.fmu_runner import FmuAgentPolicy
    from bridge.errors import ConfigError
    from bridge.experiment.config import load_experiment
    from bridge.experiment.validate import resolve_fmu
    from bridge.fmu import read_model_info

    run = runs["DQN-cartpole_balance"]
    export_fmu(run, "2")
    experiment = load_experiment(example_experiment("dcmotor_tracking"))
    info = read_model_info(resolve_fmu(experiment))
    task = Task(experiment, info.variables, timing(experiment, info))
    policy = FmuAgentPolicy(run)
    try:
        with pytest.raises(ConfigError, match=r"reads \['x', 'x_dot', 'theta', 'theta_dot'\] and acts on"):
            policy.reset(task, None)
    finally:
        policy.close()
    with pytest.raises(ConfigError, match="export fmu"):
        FmuAgentPolicy(run / "checkpoints")
