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
sample_timeout_s   ``env_runners(sample_timeout_s=...)``: how long an env runner may take for one
                   sample before RLlib drops it (``--sample-timeout-s``); unset (the default):
                   as long as the plant takes, where RLlib's own default is 60 s
normalize          must be false (RLlib trains on the Task's observations as they are)
PPO hyperparams:
  learning_rate    ``lr``; ``lin_X`` is a linear decay from X to 0 over ``timesteps``
  n_steps          steps per env and iteration: ``train_batch_size_per_learner``
                   = n_steps x n_envs x runners
  batch_size       ``minibatch_size``
  n_epochs         ``num_epochs``
  gamma            ``gamma``
  gae_lambda       ``lambda_``
  clip_range       ``clip_param``; RLlib's PPO has no clip schedule: ``lin_X`` trains with
                   the constant X (logged)
  ent_coef         ``entropy_coeff``; ``lin_X`` is a linear decay from X to 0
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

The env is registered under a stable name, ``fmu_bridge/<experiment name>``
(``bridge.env.rllib.register``): :func:`restore` registers it again and returns the Algorithm of a
run's checkpoint in a fresh process. ``train --resume RUN`` (:func:`train_rllib` with ``resume``)
continues an RLlib run from its last checkpoint for ``timesteps`` more env steps.

An iteration that brings no new samples while every env runner is healthy (each slower than
``sample_timeout_s``) ends the run with a :class:`TrainingStalled` that names the setting; the env
runners are then stopped at once (killed), not waited for while they finish their slow samples. One
whose runner died is logged and training goes on: Ray restarts the runner (within the
``env_runner_restore_timeout_s`` set below).

The exported action is the one RLlib's env runners take with ``explore=False``: the arg max of
the logits (discrete), else the distribution's deterministic value (the Gaussian mean, for SAC
too: RLlib does not squash it) mapped from [-1, 1] onto the action space and clipped to it.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.run_state import training_lock
from agents.settings import TrainingSettings
from bridge.errors import BridgeError, ConfigError
from bridge.experiment.config import load_experiment

_log = logging.getLogger(__name__)

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


class TrainingStalled(BridgeError):
    """An RLlib iteration brought no new samples: every env runner took longer than
    ``training.sample_timeout_s`` for its sample (RLlib drops late samples)."""


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
            if ours == "ent_coef" and _is_schedule(hyper[ours]):
                kwargs[theirs] = _schedule(hyper[ours], ours, settings.timesteps)
            else:
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
        clip = hyper["clip_range"]
        if _is_schedule(clip):  # RLlib's PPO reads clip_param as one number
            _log.warning(
                "training.hyperparams.clip_range %s: RLlib's PPO has no clip schedule; training with "
                "the constant %s",
                clip,
                clip[4:],
            )
            clip = clip[4:]
        kwargs["clip_param"] = _number(clip, "clip_range")
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
    if _is_schedule(value):
        return _schedule(value, "learning_rate", timesteps)
    return _number(value, "learning_rate")


def _is_schedule(value: Any) -> bool:
    return isinstance(value, str) and value.startswith("lin_")


def _schedule(value: str, name: str, timesteps: int) -> list[list[float]]:
    """RL Zoo's ``lin_X`` (X at the start, 0 at ``timesteps``) as an RLlib schedule."""
    return [[0, _number(value[4:], name)], [timesteps, 0.0]]


def _number(value: Any, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(
            f"training.hyperparams.{name}: {value!r} is not a number; train --engine rllib takes numbers "
            "(and lin_X for learning_rate, ent_coef and clip_range)"
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
    # None: wait for every sample as long as the plant takes (RLlib's own default drops samples
    # slower than 60 s and returns an iteration without any)
    config = config.env_runners(sample_timeout_s=settings.sample_timeout_s)
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
    experiment_path: Path | None,
    *,
    run_dir: Path | None,
    overrides: dict[str, Any] | None = None,
    runners: int | None = None,
    version: str | None = None,
    ray_address: str | None = None,
    on_iteration: Callable[[Any, dict[str, Any]], None] | None = None,
    resume: Path | None = None,
) -> RllibResult:
    """Train PPO or SAC on RLlib until ``timesteps`` env steps; ``on_iteration(algo, result)`` after
    each; then export the policy (:func:`export_policy`). ``run_dir`` must be new or empty.

    ``resume``: an RLlib run folder to continue from its newest checkpoint for ``timesteps`` more
    env steps (the run's own experiment and settings; ``overrides`` and ``runners`` win)."""
    from agents.ray_engine import check_resources, connect

    if resume is not None:
        run_dir, experiment_path, info, settings = _resumed(resume, overrides or {})
        version = info["version"]
        runners = int(info.get("runners", 1)) if runners is None else runners
    elif experiment_path is None:
        raise ConfigError("train --engine rllib: give an experiment file, or --resume RUN")
    experiment = load_experiment(experiment_path, version=version)
    if resume is None:
        settings = TrainingSettings.from_experiment(experiment, overrides or {})
    runners = 1 if runners is None else runners
    config = build_config(experiment_path, settings, runners=runners, version=version)
    ray = connect(ray_address)
    licence = experiment.model.licence
    if licence is not None and settings.vec != "remote":  # nodes hold the instances there
        check_resources(ray, {licence.resource: licence.per_instance * max(1, settings.n_envs)})
    if resume is None:
        run_dir, info = _new_run(experiment, experiment_path, settings, run_dir, runners)
    assert run_dir is not None
    info.pop("error", None)  # a resumed run's last failure is in its log, not its state
    info.update(runners=runners, status="running")
    with training_lock(run_dir):  # held while it trains: a killed run is found interrupted
        return _train_held(
            config, settings, run_dir, info, resuming=resume is not None, on_iteration=on_iteration
        )


def _new_run(
    experiment: Any, experiment_path: Path, settings: TrainingSettings, run_dir: Path | None, runners: int
) -> tuple[Path, dict[str, Any]]:
    from agents.train import prepare_run_dir
    from bridge.env.plants import model_info_for
    from bridge.fmu.vocab import summary_of

    run_dir = prepare_run_dir(settings, experiment, experiment_path, run_dir)
    # the variables the Task was built from: a deployed agent needs them, not the FMU (as SB3 runs)
    (run_dir / "model.json").write_text(json.dumps(summary_of(model_info_for(experiment)), indent=2))
    info: dict[str, Any] = {
        "engine": "rllib",
        "algo": settings.algo.upper(),
        "runners": runners,
        "n_envs": settings.n_envs,
        "experiment": str(experiment_path),
        "version": experiment.version,
        "seed": settings.seed,
        "settings": settings.model_dump(mode="json"),
        "timesteps": 0,
        "iterations": 0,
    }
    return run_dir, info


def _resumed(run_dir: Path, overrides: dict[str, Any]) -> tuple[Path, Path, dict[str, Any], TrainingSettings]:
    """(run folder, its experiment, its run.json, its settings with ``overrides``) of an RLlib run."""
    from pydantic import ValidationError

    info_file = run_dir / "run.json"
    info = json.loads(info_file.read_text()) if info_file.is_file() else {}
    if info.get("engine") != "rllib":
        raise ConfigError(
            f"--resume {run_dir}: not an RLlib run folder (expected run.json with engine rllib from "
            "`fmu-bridge train --engine rllib`); resume SB3 runs without --engine rllib"
        )
    if "settings" not in info:
        raise ConfigError(f"--resume {run_dir}: its run.json has no training settings (an older run)")
    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        settings = TrainingSettings.model_validate({**info["settings"], **given})
    except ValidationError as exc:
        raise ConfigError(f"--resume {run_dir}: invalid training settings: {exc}") from None
    return run_dir, run_dir / "experiment.yaml", info, settings


def newest_checkpoint(run_dir: Path) -> Path:
    """The checkpoint a resumed or restored run starts from: ``RUN/checkpoint`` (saved at the end)
    if it is newer than every ``RUN/checkpoints/iter_N``, else the highest N."""
    saved = sorted(
        (int(p.name[5:]), p) for p in (run_dir / "checkpoints").glob("iter_*") if p.name[5:].isdigit()
    )
    final = run_dir / "checkpoint"
    candidates = [p for _, p in saved[-1:]] + ([final] if final.is_dir() else [])
    if not candidates:
        raise ConfigError(
            f"{run_dir}: the run has no checkpoint to continue from (its training ended before the "
            "first iteration); train it again"
        )
    return max(candidates, key=lambda p: p.stat().st_mtime).resolve()


def _train_held(
    config: Any,
    settings: TrainingSettings,
    run_dir: Path,
    info: dict[str, Any],
    *,
    resuming: bool,
    on_iteration: Callable[[Any, dict[str, Any]], None] | None,
) -> RllibResult:
    (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    algo = config.build_algo()
    base = int(info.get("timesteps", 0)) if resuming else 0
    if resuming:
        algo.restore_from_path(str(newest_checkpoint(run_dir)))
        info.setdefault("resumed", []).append({"at": base, "timesteps": settings.timesteps})
    start = time.perf_counter()
    steps, iterations, done = base, int(info.get("iterations", 0)), False
    try:
        while steps < base + settings.timesteps:
            result = algo.train()
            iterations += 1
            steps = _sampled(result, steps, iterations, settings, _all_healthy(algo))
            algo.save_to_path(str((run_dir / "checkpoints" / f"iter_{iterations}").resolve()))
            if on_iteration is not None:
                on_iteration(algo, result)
        checkpoint = (run_dir / "checkpoint").resolve()
        algo.save_to_path(str(checkpoint))
        done = True
    except KeyboardInterrupt:
        info["status"] = "interrupted"
        raise
    except BaseException as exc:
        info["status"], info["error"] = "failed", f"{type(exc).__name__}: {exc}"
        raise
    finally:
        info.update(timesteps=steps, iterations=iterations)
        info["wall_time_s"] = float(info.get("wall_time_s", 0.0)) + time.perf_counter() - start
        (run_dir / "run.json").write_text(json.dumps(info, indent=2))
        if not done:  # runners may be deep in a slow sample: stop them now, not after it
            algo.env_runner_group.reset([])
        algo.stop()
    onnx = export_policy(run_dir, info["algo"])
    info["status"] = "done"
    (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    return RllibResult(run_dir, steps, iterations, info["wall_time_s"], checkpoint, onnx)


def _sampled(
    result: dict[str, Any], before: int, iteration: int, settings: TrainingSettings, healthy: bool
) -> int:
    """The env steps sampled so far, from an iteration's result. An iteration without new samples
    while every env runner is healthy means they were slower than ``sample_timeout_s`` (RLlib
    drops late samples): :class:`TrainingStalled`, naming the setting. One whose runners died is
    logged: Ray restarts them for the next iteration."""
    steps = result.get("env_runners", {}).get("num_env_steps_sampled_lifetime")
    if steps is not None and int(steps) > before:
        return int(steps)
    limit = settings.sample_timeout_s
    if healthy and limit is not None:
        raise TrainingStalled(
            f"RLlib iteration {iteration} brought no new samples (env steps sampled: {before:,}): every "
            f"env runner took longer than training.sample_timeout_s = {limit:g} s for its sample, and "
            "RLlib drops late samples. The plant is slower than that setting allows: raise "
            "training.sample_timeout_s (--sample-timeout-s), or unset it to wait as long as the plant takes"
        )
    _log.warning("RLlib iteration %d brought no samples: env runners failed, Ray restarts them", iteration)
    return before


def _all_healthy(algo: Any) -> bool:
    group = algo.env_runner_group
    return bool(group.num_healthy_remote_env_runners() == group.num_remote_env_runners())


def restore(run_dir: Path, *, ray_address: str | None = None) -> Any:
    """The RLlib ``Algorithm`` of an RLlib run's newest checkpoint, in this process: registers the
    run's experiment under its stable env name (``bridge.env.rllib.register``, nodes included for
    ``vec: remote``), then ``Algorithm.from_checkpoint``."""
    from agents.ray_engine import connect

    _, experiment_path, info, settings = _resumed(run_dir, {})
    build_config(experiment_path, settings, runners=int(info.get("runners", 1)), version=info["version"])
    connect(ray_address)
    from ray.rllib.algorithms.algorithm import Algorithm

    return Algorithm.from_checkpoint(str(newest_checkpoint(run_dir)))


def export_policy(run_dir: Path, algo: str) -> Path:
    """``RUN/rllib_policy.npz`` from ``RUN/checkpoint``, then ``RUN/policy.onnx`` through the ONNX
    export of SB3 runs (``agents.export.onnx``)."""
    from agents.export.onnx import export_onnx
    from agents.export.rllib_policy import write_policy

    write_policy(run_dir / "checkpoint", run_dir, algo)
    return export_onnx(run_dir)
