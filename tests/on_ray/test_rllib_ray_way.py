"""RLlib used the Ray way: the experiment's env registered under a stable name that a stock
PPOConfig samples whole episodes from; a run's checkpoint restored by ``Algorithm.from_checkpoint``
in a fresh process; ``train --engine rllib --resume``; the example's own training section (lin_X
schedules) on RLlib; a slow plant on two Ray nodes with no sample timeout, and one slower than the
sample timeout a user set ending the run with that setting named."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("ray.rllib")

from ray.rllib.algorithms.ppo import PPOConfig
from typer.testing import CliRunner

from agents.rllib_train import TrainingStalled, build_config, train_rllib
from agents.settings import TrainingSettings
from bridge.cli.main import _load_plugins, app
from bridge.env.batch import BatchVectorEnv
from bridge.env.rllib import register
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from tests.on_ray.test_rllib_autoreset import cartpole, episode_faults, sample
from tests.on_ray.test_rllib_export import rllib_actions
from tests.slow_plant import slow_experiment


@pytest.mark.parametrize("vectorize", ["sync", "vector_entry_point"])
def test_a_stock_ppo_config_over_the_registered_env_records_episodes_that_start_in_reset_states(
    vectorize: str,
) -> None:
    """No callback, no project config: ``PPOConfig().environment("fmu_bridge/<name>")``, under
    RLlib's default vectorisation (SyncVectorEnv over FmuEnv) and over the batch env."""
    name = register(example_experiment("cartpole_balance"))
    assert name == "fmu_bridge/cartpole-balance"
    config = PPOConfig().environment(name)
    if vectorize == "vector_entry_point":
        config = config.env_runners(num_envs_per_env_runner=4, gym_env_vectorize_mode=vectorize)
    else:
        config = config.env_runners(num_envs_per_env_runner=2)
    episodes = sample(config)
    names = BatchVectorEnv(cartpole(), 1).engine.task.output_names
    finished = [e for e in episodes if e.is_done]
    assert len(finished) >= 6, f"only {len(finished)} episodes ended: sample longer"
    assert episode_faults(episodes, names) == []


RESTORE = """
import json, sys
from pathlib import Path
import numpy as np, torch
from agents.rllib_train import restore
algo = restore(Path(sys.argv[1]), ray_address=sys.argv[2])
sizes = algo.env_runner_group.foreach_env_runner(lambda r: r.env.num_envs, local_env_runner=False)
obs = torch.as_tensor(np.load(sys.argv[3]))
with torch.no_grad():
    logits = algo.get_module().forward_inference({"obs": obs})["action_dist_inputs"]
print(json.dumps({"env": algo.config.env, "sizes": sizes, "actions": logits.argmax(-1).tolist()}))
algo.stop()
"""


@pytest.fixture(scope="module")
def example_run(ray_cluster: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``train examples/cartpole_balance.yaml --engine rllib``: the example's own training section
    (lin_0.001 learning rate, lin_0.2 clip range, 8 envs), cut to one iteration."""
    _load_plugins()  # the agents' commands (train) on the app, as the fmu-bridge command does
    run = tmp_path_factory.mktemp("rllib_example") / "run"
    args = ["train", str(example_experiment("cartpole_balance")), "--engine", "rllib"]
    args += ["--timesteps", "256", "--run-dir", str(run), "--ray-address", ray_cluster.address]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    return run


def test_the_examples_training_section_trains_on_rllib(example_run: Path) -> None:
    info = json.loads((example_run / "run.json").read_text())
    assert info["status"] == "done" and info["timesteps"] >= 256, info
    assert info["settings"]["hyperparams"]["clip_range"] == "lin_0.2"
    assert (example_run / "policy.onnx").is_file()


def test_algorithm_from_checkpoint_restores_a_run_in_a_fresh_process(
    ray_cluster: Any, example_run: Path, tmp_path: Path
) -> None:
    observations = np.random.default_rng(0).uniform(-0.2, 0.2, size=(32, 4)).astype(np.float32)
    np.save(tmp_path / "obs.npy", observations)
    script = [sys.executable, "-c", RESTORE, str(example_run), ray_cluster.address, str(tmp_path / "obs.npy")]
    done = subprocess.run(script, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-4000:]
    restored = json.loads(done.stdout.strip().splitlines()[-1])
    assert restored["env"] == "fmu_bridge/cartpole-balance"
    assert restored["sizes"] == [8], "the restored env runner hosts the run's batch env"
    expected = rllib_actions(example_run / "checkpoint", observations)
    assert restored["actions"] == expected.tolist()


def test_train_resume_continues_an_rllib_run(ray_cluster: Any, example_run: Path) -> None:
    before = json.loads((example_run / "run.json").read_text())
    args = ["train", "--engine", "rllib", "--resume", str(example_run), "--timesteps", "256"]
    result = CliRunner().invoke(app, [*args, "--ray-address", ray_cluster.address])
    assert result.exit_code == 0, result.output
    after = json.loads((example_run / "run.json").read_text())
    assert after["status"] == "done"
    assert after["timesteps"] >= before["timesteps"] + 256, (before, after)
    assert after["resumed"] == [{"at": before["timesteps"], "timesteps": 256}]
    assert after["iterations"] > before["iterations"]
    assert (example_run / "checkpoints" / f"iter_{after['iterations']}").is_dir()


SLOW_TRAINING = """training:
  algo: PPO
  timesteps: 16
  n_envs: 1
  seed: 1
  hyperparams: {n_steps: 8, batch_size: 8, n_epochs: 1, policy_kwargs: {net_arch: [8]}}
"""


@pytest.mark.slow
def test_a_slow_plant_trains_on_two_ray_nodes_with_no_sample_timeout(
    ray_cluster: Any, tmp_path: Path
) -> None:
    """Two env runners, one per Ray node, each stepping the slow plant (0.2 s a step, 1 s to
    initialise): RLlib waits for every sample as long as the plant takes (its own default would
    drop samples slower than 60 s)."""
    path = slow_experiment(tmp_path, step_delay_s=0.2, init_delay_s=1.0, duration_s=1.0, tail=SLOW_TRAINING)
    settings = TrainingSettings.from_experiment(load_experiment(path), {})
    assert build_config(path, settings, runners=2).sample_timeout_s is None
    hosts: list[Any] = []

    def node_id(runner: Any) -> str:  # defined here: Ray ships it by value, not by module name
        import ray

        return str(ray.get_runtime_context().get_node_id())

    def on_iteration(algo: Any, result: dict[str, Any]) -> None:
        hosts.extend(algo.env_runner_group.foreach_env_runner(node_id, local_env_runner=False))

    result = train_rllib(path, run_dir=tmp_path / "run", runners=2, on_iteration=on_iteration)
    assert result.timesteps >= 16
    assert len(set(hosts)) == 2, f"the env runners did not run on both Ray nodes: {hosts}"


@pytest.mark.slow
def test_a_sample_slower_than_the_set_sample_timeout_ends_the_run_naming_the_setting(
    ray_cluster: Any, tmp_path: Path
) -> None:
    path = slow_experiment(tmp_path, step_delay_s=0.3, duration_s=1.0, tail=SLOW_TRAINING)
    run = tmp_path / "run"
    with pytest.raises(TrainingStalled, match=r"training.sample_timeout_s = 0.5 s.*--sample-timeout-s"):
        train_rllib(path, run_dir=run, runners=1, overrides={"sample_timeout_s": 0.5})
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "failed" and "TrainingStalled" in info["error"], info


@pytest.mark.slow
def test_the_ray_tune_example_runs_a_grid_over_an_experiment(ray_cluster: Any, tmp_path: Path) -> None:
    """examples/rllib_tune.py on the test cluster: two trials (two learning rates), each PPO over
    the registered env until its env steps, each with a checkpoint."""
    script = Path(__file__).parents[2] / "examples" / "rllib_tune.py"
    args = [sys.executable, str(script), str(example_experiment("cartpole_balance"))]
    args += ["--lr", "0.001", "--lr", "0.0003", "--timesteps", "256", "--runners", "0"]
    args += ["--out", str(tmp_path / "tune"), "--ray-address", ray_cluster.address]
    done = subprocess.run(args, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-4000:]
    text = "\n" + done.stdout  # Tune prints its status first: the result list starts at the last "[" line
    rows = json.loads(text[text.rindex("\n[\n") :])
    assert sorted(row["lr"] for row in rows) == [0.0003, 0.001]
    assert all(row["error"] is None and row["env_steps"] >= 256 and row["checkpoint"] for row in rows), rows
