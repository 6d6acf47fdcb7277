"""``fmu-bridge train --engine rllib``: the experiment's ``training:`` section on RLlib's PPO or SAC.

Each env runner hosts a NEXT_STEP batch env of ``n_envs`` FMU instances (``bridge.env.rllib``);
runners that die are restarted by Ray and training goes on; checkpoints go to the run folder
(``RUN/checkpoints/iter_N``, the last one also to ``RUN/checkpoint``). At the end the policy's
deterministic path is written to ``RUN/rllib_policy.npz`` and exported to ``RUN/policy.onnx``
through the same ONNX export as SB3 runs (``agents.export``), so ``agent run --runtime onnx``,
``agent check --runtime onnx`` and ``evaluate RUN`` deploy it unchanged. A documented subset of
the section maps onto RLlib (anything else is refused with the list):

=================  ==============================================================
training           RLlib
=================  ==============================================================
algo               PPO or SAC
timesteps          env steps sampled before training stops
n_envs             FMU instances per env runner (``num_envs_per_env_runner``)
vec                ``remote``: each runner drives n_envs nodes of ``training.remote``
                   (leased, a dead node replaced by a spare); anything else: a batch env
seed               ``debugging(seed=...)``
normalize          must be false (RLlib trains on the Task's observations as they are)
PPO hyperparams:
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
SAC hyperparams:
  learning_rate    ``actor_lr``, ``critic_lr`` and ``alpha_lr`` (SB3 uses one rate for all
                   three); ``lin_X`` as for PPO
  buffer_size      ``replay_buffer_config["capacity"]`` (RLlib's default buffer type)
  learning_starts  ``num_steps_sampled_before_learning_starts``
  batch_size       ``train_batch_size_per_learner``
  gamma, tau       ``gamma``, ``tau``
  ent_coef         ``auto`` (RLlib's default) or ``auto_X``: ``initial_alpha`` X (RLlib's SAC
                   always learns the coefficient: a fixed number is refused)
  target_entropy   ``auto`` or a number: ``target_entropy``
  policy_kwargs    ``net_arch`` -> ``fcnet_hiddens`` (policy and Q networks, as in SB3)
=================  ==============================================================

The exported action is the one RLlib's env runners take with ``explore=False``: the arg max of
the logits (discrete), else the distribution's deterministic value (the Gaussian mean, for SAC
too: RLlib does not squash it) mapped from [-1, 1] onto the action space and clipped to it.
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

SUPPORTED = {
    "PPO": [
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
    ],
    "SAC": [
        "learning_rate",
        "buffer_size",
        "learning_starts",
        "batch_size",
        "gamma",
        "tau",
        "ent_coef",
        "target_entropy",
        "policy_kwargs",
    ],
}
_SAME = {
    "PPO": {
        "gamma": "gamma",
        "gae_lambda": "lambda_",
        "ent_coef": "entropy_coeff",
        "vf_coef": "vf_loss_coeff",
        "max_grad_norm": "grad_clip",
    },
    "SAC": {"gamma": "gamma", "tau": "tau"},
}


@dataclass
class RllibResult:
    run_dir: Path
    timesteps: int
    iterations: int
    wall_time_s: float
    checkpoint: Path
    onnx: Path


def training_kwargs(settings: TrainingSettings, runners: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """(``config.training`` keywords, ``rl_module`` model_config) from the section; refuses what
    is not in the documented subset."""
    algo = settings.algo.upper()
    if algo not in SUPPORTED:
        raise ConfigError(
            f"train --engine rllib runs {' or '.join(SUPPORTED)}; the experiment asks for {settings.algo} "
            "(train it with --engine sb3)"
        )
    if settings.normalize:
        raise ConfigError(
            "training.normalize: train --engine rllib trains on the Task's observations as they are "
            "(no VecNormalize); set normalize: false, or train with --engine sb3"
        )
    if settings.residual is not None:
        raise ConfigError(
            "training.residual: train --engine rllib has no residual policies; use --engine sb3"
        )
    hyper = dict(settings.hyperparams)
    unknown = sorted(set(hyper) - set(SUPPORTED[algo]))
    if unknown:
        raise ConfigError(
            f"training.hyperparams {unknown} have no RLlib {algo} mapping here; supported: "
            f"{SUPPORTED[algo]} (see agents/rllib_train.py)"
        )
    kwargs = _ppo_kwargs(settings, hyper, runners) if algo == "PPO" else _sac_kwargs(settings, hyper)
    for ours, theirs in _SAME[algo].items():
        if ours in hyper:
            kwargs[theirs] = _number(hyper[ours], ours)
    model: dict[str, Any] = {}
    policy = dict(hyper.get("policy_kwargs") or {})
    if set(policy) - {"net_arch"} or not isinstance(policy.get("net_arch", []), list):
        raise ConfigError(f"policy_kwargs {policy}: train --engine rllib takes net_arch: [sizes] only")
    if "net_arch" in policy:
        model["fcnet_hiddens"] = [int(n) for n in policy["net_arch"]]
    return kwargs, model


def _ppo_kwargs(settings: TrainingSettings, hyper: dict[str, Any], runners: int) -> dict[str, Any]:
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
    return kwargs


def _sac_kwargs(settings: TrainingSettings, hyper: dict[str, Any]) -> dict[str, Any]:
    kwargs: dict[str, Any] = {}
    if "learning_rate" in hyper:
        rate = _learning_rate(hyper["learning_rate"], settings.timesteps)
        kwargs.update(actor_lr=rate, critic_lr=rate, alpha_lr=rate)
    if "buffer_size" in hyper:
        kwargs["replay_buffer_config"] = {"capacity": int(_number(hyper["buffer_size"], "buffer_size"))}
    if "learning_starts" in hyper:
        starts = int(_number(hyper["learning_starts"], "learning_starts"))
        kwargs["num_steps_sampled_before_learning_starts"] = starts
    if "batch_size" in hyper:
        kwargs["train_batch_size_per_learner"] = int(_number(hyper["batch_size"], "batch_size"))
    coef = hyper.get("ent_coef", "auto")
    if isinstance(coef, str) and coef.startswith("auto_"):
        kwargs["initial_alpha"] = _number(coef[5:], "ent_coef")
    elif coef != "auto":
        raise ConfigError(
            f"training.hyperparams.ent_coef: {coef!r}; RLlib's SAC always learns its entropy "
            "coefficient: use auto or auto_X (X the initial value), or train with --engine sb3"
        )
    target = hyper.get("target_entropy", "auto")
    if target != "auto":
        kwargs["target_entropy"] = _number(target, "target_entropy")
    return kwargs


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
    from bridge.env.rllib import algo_config

    experiment = load_experiment(experiment_path, version=version)
    kwargs, model = training_kwargs(settings, runners)
    nodes: dict[str, Any] = {}
    if settings.vec == "remote":  # each runner leases n_envs nodes from the pool
        remote = settings.remote
        nodes = {
            "nodes": remote.nodes,
            "options": remote.options(),
            "timeout_s": remote.timeout_s,
            "replace_wait_s": max(remote.replace_wait_s, 60.0),
            "prefix": experiment.node.prefix,
        }
    config = algo_config(
        settings.algo.upper(),
        experiment,
        envs_per_runner=max(1, settings.n_envs),
        num_env_runners=runners,
        **nodes,
    )
    config = config.training(**kwargs).debugging(seed=settings.seed)
    licence = experiment.model.licence
    if licence is not None and not nodes:  # each env runner holds n_envs instances' seats
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
    run_dir: Path | None,
    overrides: dict[str, Any] | None = None,
    runners: int = 1,
    version: str | None = None,
    ray_address: str | None = None,
    on_iteration: Callable[[Any, dict[str, Any]], None] | None = None,
) -> RllibResult:
    """Train PPO or SAC on RLlib until ``timesteps`` env steps; ``on_iteration(algo, result)`` after
    each; then export the policy (:func:`export_policy`). ``run_dir`` must be new or empty."""
    from agents.ray_engine import check_resources, connect
    from agents.train import prepare_run_dir
    from bridge.env.plants import model_info_for
    from bridge.fmu.vocab import summary_of

    experiment = load_experiment(experiment_path, version=version)
    settings = TrainingSettings.from_experiment(experiment, overrides or {})
    config = build_config(experiment_path, settings, runners=runners, version=version)
    ray = connect(ray_address)
    licence = experiment.model.licence
    if licence is not None and settings.vec != "remote":  # nodes hold the instances there
        check_resources(ray, {licence.resource: licence.per_instance * max(1, settings.n_envs)})
    run_dir = prepare_run_dir(settings, experiment, experiment_path, run_dir)
    # the variables the Task was built from: a deployed agent needs them, not the FMU (as SB3 runs)
    (run_dir / "model.json").write_text(json.dumps(summary_of(model_info_for(experiment)), indent=2))
    info: dict[str, Any] = {
        "engine": "rllib",
        "algo": settings.algo.upper(),
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
        onnx = export_policy(run_dir, info["algo"])
        info["status"] = "done"
        (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    return RllibResult(run_dir, steps, iterations, info["wall_time_s"], checkpoint, onnx)


def export_policy(run_dir: Path, algo: str) -> Path:
    """``RUN/rllib_policy.npz`` from ``RUN/checkpoint``, then ``RUN/policy.onnx`` through the ONNX
    export of SB3 runs (``agents.export.onnx``)."""
    from agents.export.onnx import export_onnx
    from agents.export.rllib_policy import write_policy

    write_policy(run_dir / "checkpoint", run_dir, algo)
    return export_onnx(run_dir)
