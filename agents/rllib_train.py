"""``fmu-bridge train --engine rllib``: the experiment's ``training:`` section on RLlib's PPO.

Each env runner hosts a NEXT_STEP batch env of ``n_envs`` FMU instances (``bridge.env.rllib``);
runners that die are restarted by Ray and training goes on; checkpoints go to the run folder
(``RUN/checkpoints/iter_N``, the last one also to ``RUN/checkpoint``). A documented subset of the
section maps onto RLlib (anything else is refused with the list):

=================  ==============================================================
training           RLlib PPO
=================  ==============================================================
algo               PPO only
timesteps          env steps sampled before training stops
n_envs             FMU instances per env runner (``num_envs_per_env_runner``)
seed               ``debugging(seed=...)``
hyperparams:
  learning_rate    ``lr``; ``lin_X`` is a linear decay from X to 0 over ``timesteps``
  n_steps          steps per env and iteration: ``train_batch_size_per_learner``
                   = n_steps x n_envs x runners
  batch_size       ``minibatch_size``
  n_epochs         ``num_epochs``
  gamma            ``gamma``
  gae_lambda       ``lambda_``
  clip_range       ``clip_param`` (a number)
  ent_coef         ``entropy_coeff``
  vf_coef          ``vf_loss_coeff``
  max_grad_norm    ``grad_clip``
  policy_kwargs    ``net_arch`` (a list of layer sizes) -> ``fcnet_hiddens``
=================  ==============================================================
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.run_state import training_lock
from agents.settings import TrainingSettings
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment

SUPPORTED = [
    "learning_rate",
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "clip_range",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "policy_kwargs",
]
_SAME = {
    "gamma": "gamma",
    "gae_lambda": "lambda_",
    "ent_coef": "entropy_coeff",
    "vf_coef": "vf_loss_coeff",
    "max_grad_norm": "grad_clip",
}


@dataclass
class RllibResult:
    run_dir: Path
    timesteps: int
    iterations: int
    wall_time_s: float
    checkpoint: Path


def training_kwargs(settings: TrainingSettings, runners: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """(``config.training`` keywords, ``rl_module`` model_config) from the section; refuses what
    is not in the documented subset."""
    if settings.algo.upper() != "PPO":
        raise ConfigError(f"train --engine rllib runs PPO; the experiment asks for {settings.algo}")
    hyper = dict(settings.hyperparams)
    unknown = sorted(set(hyper) - set(SUPPORTED))
    if unknown:
        raise ConfigError(
            f"training.hyperparams {unknown} have no RLlib mapping here; supported: {SUPPORTED} "
            "(see agents/rllib_train.py)"
        )
    n_envs = max(1, settings.n_envs)
    n_steps = int(hyper.get("n_steps", 128))
    kwargs: dict[str, Any] = {"train_batch_size_per_learner": n_steps * n_envs * max(1, runners)}
    if "batch_size" in hyper:
        kwargs["minibatch_size"] = int(hyper["batch_size"])
    if "n_epochs" in hyper:
        kwargs["num_epochs"] = int(hyper["n_epochs"])
    if "learning_rate" in hyper:
        kwargs["lr"] = _learning_rate(hyper["learning_rate"], settings.timesteps)
    if "clip_range" in hyper:
        kwargs["clip_param"] = _number(hyper["clip_range"], "clip_range")
    for ours, theirs in _SAME.items():
        if ours in hyper:
            kwargs[theirs] = _number(hyper[ours], ours)
    model: dict[str, Any] = {}
    policy = dict(hyper.get("policy_kwargs") or {})
    if set(policy) - {"net_arch"} or not isinstance(policy.get("net_arch", []), list):
        raise ConfigError(f"policy_kwargs {policy}: train --engine rllib takes net_arch: [sizes] only")
    if "net_arch" in policy:
        model["fcnet_hiddens"] = [int(n) for n in policy["net_arch"]]
    return kwargs, model


def _learning_rate(value: Any, timesteps: int) -> Any:
    if isinstance(value, str) and value.startswith("lin_"):
        start = _number(value[4:], "learning_rate")
        return [[0, start], [timesteps, 0.0]]
    return _number(value, "learning_rate")


def _number(value: Any, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(
            f"training.hyperparams.{name}: {value!r} is not a number; train --engine rllib takes numbers "
            "(and lin_X for learning_rate)"
        ) from None


def build_config(
    experiment_path: Path, settings: TrainingSettings, *, runners: int, version: str | None = None
) -> Any:
    from bridge.env.rllib import ppo_config

    experiment = load_experiment(experiment_path, version=version)
    kwargs, model = training_kwargs(settings, runners)
    config = ppo_config(experiment, envs_per_runner=max(1, settings.n_envs), num_env_runners=runners)
    config = config.training(**kwargs).debugging(seed=settings.seed)
    licence = experiment.model.licence
    if licence is not None:  # each env runner holds n_envs instances' seats
        seats = {licence.resource: licence.per_instance * max(1, settings.n_envs)}
        config = config.env_runners(custom_resources_per_env_runner=seats)
    if model:
        config = config.rl_module(model_config=model)
    return config.fault_tolerance(
        restart_failed_env_runners=True,
        env_runner_restore_timeout_s=120.0,
        delay_between_env_runner_restarts_s=1.0,
    )


def train_rllib(
    experiment_path: Path,
    *,
    run_dir: Path,
    overrides: dict[str, Any] | None = None,
    runners: int = 1,
    version: str | None = None,
    ray_address: str | None = None,
    on_iteration: Callable[[Any, dict[str, Any]], None] | None = None,
) -> RllibResult:
    """Train PPO on RLlib until ``timesteps`` env steps; ``on_iteration(algo, result)`` after each."""
    from agents.ray_engine import check_resources, connect

    experiment = load_experiment(experiment_path, version=version)
    settings = TrainingSettings.from_experiment(experiment, overrides or {})
    config = build_config(experiment_path, settings, runners=runners, version=version)
    ray = connect(ray_address)
    licence = experiment.model.licence
    if licence is not None:
        check_resources(ray, {licence.resource: licence.per_instance * max(1, settings.n_envs)})
    run_dir.mkdir(parents=True, exist_ok=True)
    info: dict[str, Any] = {
        "engine": "rllib",
        "algo": "PPO",
        "runners": runners,
        "n_envs": settings.n_envs,
        "experiment": str(experiment_path),
        "seed": settings.seed,
        "status": "running",
    }
    with training_lock(run_dir):  # held while it trains: a killed run is found interrupted
        (run_dir / "run.json").write_text(json.dumps(info, indent=2))
        algo = config.build_algo()
        start = time.perf_counter()
        steps, iterations = 0, 0
        try:
            while steps < settings.timesteps:
                result = algo.train()
                iterations += 1
                steps = int(result["env_runners"]["num_env_steps_sampled_lifetime"])
                algo.save_to_path(str((run_dir / "checkpoints" / f"iter_{iterations}").resolve()))
                if on_iteration is not None:
                    on_iteration(algo, result)
            checkpoint = (run_dir / "checkpoint").resolve()
            algo.save_to_path(str(checkpoint))
            info["status"] = "done"
        except KeyboardInterrupt:
            info["status"] = "interrupted"
            raise
        except BaseException as exc:
            info["status"], info["error"] = "failed", f"{type(exc).__name__}: {exc}"
            raise
        finally:
            info.update(timesteps=steps, iterations=iterations, wall_time_s=time.perf_counter() - start)
            (run_dir / "run.json").write_text(json.dumps(info, indent=2))
            algo.stop()
    return RllibResult(run_dir, steps, iterations, info["wall_time_s"], checkpoint)
