"""Ray Tune over an experiment: RLlib's PPO (or SAC) on the experiment's env, a grid of learning rates.

    python examples/rllib_tune.py examples/cartpole_balance.yaml --lr 0.001 --lr 0.0003 --timesteps 20000

The env is registered under its stable name, ``fmu_bridge/<experiment name>``
(``bridge.env.rllib.register``, called by ``agents.rllib_train.build_config``): each trial's env
runners host a NEXT_STEP batch env of ``training.n_envs`` FMU instances, and the experiment's
``training:`` section gives every other setting, mapped as ``train --engine rllib`` maps it. Tune
stops a trial at ``--timesteps`` env steps, keeps its last checkpoint and reports the mean episode
return; ``Algorithm.from_checkpoint`` restores a trial's checkpoint in another process once
``register(experiment)`` has run there. Needs the ``ray`` extra (docs/ray.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ray import tune

from agents.ray_engine import connect
from agents.rllib_train import build_config
from agents.settings import TrainingSettings
from bridge.experiment.config import load_experiment

RETURN = "env_runners/episode_return_mean"
STEPS = "env_runners/num_env_steps_sampled_lifetime"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("experiment", type=Path)
    parser.add_argument("--lr", type=float, action="append", help="a learning rate of the grid (repeat)")
    parser.add_argument("--timesteps", type=int, default=20_000, help="env steps per trial")
    parser.add_argument("--runners", type=int, default=1, help="env runners per trial")
    parser.add_argument("--out", type=Path, default=Path("tune_runs"), help="Tune's storage folder")
    parser.add_argument("--ray-address", default=None, help="Ray cluster (default: $RAY_ADDRESS, else local)")
    args = parser.parse_args()

    experiment = load_experiment(args.experiment)
    settings = TrainingSettings.from_experiment(experiment, {"timesteps": args.timesteps})
    config = build_config(args.experiment, settings, runners=args.runners)  # registers the env
    config = config.training(lr=tune.grid_search(args.lr or [0.001, 0.0003]))
    connect(args.ray_address)
    tuner = tune.Tuner(
        config.algo_class,
        param_space=config,
        run_config=tune.RunConfig(
            name=experiment.name,
            storage_path=str(args.out.resolve()),
            stop={STEPS: args.timesteps},
            checkpoint_config=tune.CheckpointConfig(checkpoint_at_end=True),
        ),
    )
    results = tuner.fit()
    rows = []
    for result in results:
        metrics = result.metrics or {}
        rows.append(
            {
                "lr": result.config["lr"],
                "env_steps": metrics.get("env_runners", {}).get("num_env_steps_sampled_lifetime"),
                "return_mean": metrics.get("env_runners", {}).get("episode_return_mean"),
                "checkpoint": result.checkpoint.path if result.checkpoint else None,
                "error": str(result.error) if result.error else None,
            }
        )
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
