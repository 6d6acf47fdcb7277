"""Training with stable-baselines3 from an experiment file: ``fmu-bridge train``.

A run directory holds everything needed to reproduce and reuse the run: the experiment file
as it was, the resolved training settings, the FMU checksum, package versions and seed
(``run.json``), the final and best models, checkpoints, VecNormalize statistics, CSV and
TensorBoard logs. ``--resume RUN`` continues a run's step count.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from pydantic import ValidationError

from agents.settings import TrainingSettings, linear_schedule_kwargs, package_versions
from bridge.env.fmu_env import FmuEnv
from bridge.env.plants import model_fingerprint, model_info_for
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, load_experiment
from bridge.fmu.vocab import summary_of

_log = logging.getLogger(__name__)


@dataclass
class TrainResult:
    run_dir: Path
    timesteps: int
    wall_time_s: float
    model_path: Path


class ScenarioCycle(gym.Wrapper):  # type: ignore[type-arg]
    """For evaluation envs: cycles through held-out scenarios on reset."""

    def __init__(self, env: Any, scenarios: list[str]) -> None:
        super().__init__(env)
        self._scenarios = scenarios
        self._next = 0

    def reset(self, **kwargs: Any) -> Any:
        options = dict(kwargs.pop("options", None) or {})
        options.setdefault("scenario", self._scenarios[self._next % len(self._scenarios)])
        self._next += 1
        return self.env.reset(options=options, **kwargs)


def make_env_fn(
    experiment_path: Path,
    version: str,
    residual: dict[str, Any] | None,
    scenarios: list[str] | None = None,
    *,
    monitor: bool = False,
) -> Any:
    def build() -> Any:
        env: Any = FmuEnv(experiment_path, version=version)
        if monitor:  # evaluation envs report true episode returns through Monitor
            from stable_baselines3.common.monitor import Monitor

            env = Monitor(env)
        if residual:
            from agents.residual import ResidualWrapper

            env = ResidualWrapper(env, residual)
        if scenarios:
            env = ScenarioCycle(env, scenarios)
        return env

    return build


def build_vec_env(
    settings: TrainingSettings, experiment: Experiment, path: Path, residual: dict[str, Any] | None, seed: int
) -> Any:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if settings.vec == "remote":
        from bridge.env import RemoteVecEnv

        if residual:
            raise ConfigError("residual training runs in-process (--vec dummy or subproc)")
        remote = settings.remote
        vec = VecMonitor(
            RemoteVecEnv(  # type: ignore[arg-type]  # a registered virtual VecEnv
                path,
                remote.nodes,
                n_envs=settings.n_envs,
                options=remote.options(),
                timeout_s=remote.timeout_s,
                replace_dead=remote.replace_dead,
                replace_wait_s=remote.replace_wait_s,
            )
        )
        vec.seed(seed)
        return vec
    if settings.vec == "batch":
        return _batch_vec_env(settings, experiment, path, residual, seed)
    from stable_baselines3.common.env_util import make_vec_env

    cls = SubprocVecEnv if settings.vec == "subproc" else DummyVecEnv
    return make_vec_env(
        make_env_fn(path, experiment.version, residual), n_envs=settings.n_envs, seed=seed, vec_env_cls=cls
    )


def _batch_vec_env(
    settings: TrainingSettings, experiment: Experiment, path: Path, residual: dict[str, Any] | None, seed: int
) -> Any:
    """All ``n_envs`` FMU instances stepped in one native call (``bridge.env.batch``)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from bridge.env.batch import BatchVecEnv

    if residual:
        raise ConfigError("residual training wraps single envs: use --vec dummy or subproc, not batch")
    vec = VecMonitor(BatchVecEnv(path, settings.n_envs, version=experiment.version))  # type: ignore[arg-type]
    vec.seed(seed)
    return vec


def build_eval_env(
    train_env: Any,
    settings: TrainingSettings,
    experiment: Experiment,
    path: Path,
    residual: dict[str, Any] | None,
) -> Any:
    """One env on the held-out scenarios, of the training env's VecEnv type (SB3's EvalCallback
    warns otherwise): a worker process for subproc, a VecMonitor for remote, else in-process."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    scenarios = settings.evaluation_scenarios(experiment)
    if isinstance(train_env, VecMonitor):
        return VecMonitor(DummyVecEnv([make_env_fn(path, experiment.version, residual, scenarios)]))
    fn = make_env_fn(path, experiment.version, residual, scenarios, monitor=True)
    return SubprocVecEnv([fn]) if isinstance(train_env, SubprocVecEnv) else DummyVecEnv([fn])


def prepare_run_dir(
    settings: TrainingSettings, experiment: Experiment, path: Path, run_dir: Path | None
) -> Path:
    if run_dir is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = Path("runs") / f"{experiment.name}-{experiment.version}-{settings.algo.lower()}-{stamp}"
    if run_dir.exists() and any(run_dir.iterdir()):
        raise ConfigError(
            f"run directory {run_dir} exists and is not empty; choose another --run-dir or --resume it"
        )
    run_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy(path, run_dir / "experiment.yaml")
    return run_dir


def train(
    experiment_path: Path | None,
    *,
    overrides: dict[str, Any] | None = None,
    run_dir: Path | None = None,
    resume: Path | None = None,
    version: str | None = None,
    progress: bool = True,
) -> TrainResult:
    """Train an agent; returns where everything went."""
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    if resume is not None:
        return _resume(resume, overrides or {}, progress)
    if experiment_path is None:
        raise ConfigError("train: give an experiment file, or resume= a run directory")
    experiment = load_experiment(experiment_path, version=version)
    settings = TrainingSettings.from_experiment(experiment, overrides or {})
    residual = _residual(experiment, settings)
    run_dir = prepare_run_dir(settings, experiment, experiment_path, run_dir)
    info = _run_info(settings, experiment, residual)
    (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    # the variables the Task was built from: a deployed agent needs them, not the FMU
    (run_dir / "model.json").write_text(json.dumps(summary_of(model_info_for(experiment)), indent=2))
    env = build_vec_env(settings, experiment, experiment_path, residual, settings.seed)
    eval_env = build_eval_env(env, settings, experiment, experiment_path, residual)
    if settings.normalize:
        env = VecNormalize(env, **settings.normalize_kwargs())
        eval_env = VecNormalize(
            eval_env, training=False, norm_reward=False, **settings.normalize_kwargs(eval_env=True)
        )
    model = _new_model(settings, env, run_dir)
    model.set_logger(configure(str(run_dir / "logs"), ["csv", "tensorboard", "log"]))
    per_env = max(1, settings.n_envs)
    callbacks = CallbackList(
        [
            CheckpointCallback(
                max(settings.checkpoint_every // per_env, 1),
                str(run_dir / "checkpoints"),
                save_vecnormalize=bool(settings.normalize),
            ),
            EvalCallback(
                eval_env,
                n_eval_episodes=settings.eval_episodes,
                eval_freq=max(settings.eval_every // per_env, 1),
                best_model_save_path=str(run_dir),
                log_path=str(run_dir),
                deterministic=True,
                verbose=0,
            ),
        ]
    )
    return _learn(model, settings.timesteps, callbacks, run_dir, info, progress=progress, reset=True)


def _learn(
    model: Any,
    timesteps: int,
    callbacks: Any,
    run_dir: Path,
    info: dict[str, Any],
    *,
    progress: bool,
    reset: bool,
) -> TrainResult:
    start = time.perf_counter()
    info["status"] = "running"
    (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    try:
        model.learn(
            total_timesteps=timesteps, callback=callbacks, progress_bar=progress, reset_num_timesteps=reset
        )
        info["status"] = "done"
    except KeyboardInterrupt:
        info["status"] = "interrupted"
        _log.warning("training interrupted: saving the model so far")
    finally:
        wall = time.perf_counter() - start
        info["wall_time_s"] = info.get("wall_time_s", 0.0) + wall
        info["timesteps"] = int(model.num_timesteps)
        model.save(run_dir / "model.zip")
        env = model.get_env()
        if env is not None and hasattr(env, "save") and hasattr(env, "obs_rms"):
            env.save(str(run_dir / "vecnormalize.pkl"))
        (run_dir / "run.json").write_text(json.dumps(info, indent=2))
        if env is not None:
            env.close()
    return TrainResult(run_dir, int(model.num_timesteps), info["wall_time_s"], run_dir / "model.zip")


def _new_model(settings: TrainingSettings, env: Any, run_dir: Path) -> Any:
    import stable_baselines3 as sb3

    cls = getattr(sb3, settings.algo)
    kwargs = linear_schedule_kwargs(dict(settings.hyperparams))
    policy = kwargs.pop("policy", "MlpPolicy")
    try:
        return cls(policy, env, seed=settings.seed, device="cpu", tensorboard_log=None, verbose=0, **kwargs)
    except TypeError as exc:
        raise ConfigError(
            f"training.hyperparams: {exc} (these go to stable_baselines3.{settings.algo})"
        ) from exc


def _residual(experiment: Experiment, settings: TrainingSettings) -> dict[str, Any] | None:
    if not settings.residual:
        return None
    from agents.residual import residual_setup

    return residual_setup(experiment, settings.residual)


def _run_info(
    settings: TrainingSettings, experiment: Experiment, residual: dict[str, Any] | None
) -> dict[str, Any]:
    fmu, fmu_sha256 = model_fingerprint(experiment)
    return {
        "experiment": experiment.name,
        "version": experiment.version,
        "algo": settings.algo,
        "seed": settings.seed,
        "settings": settings.model_dump(mode="json"),
        "fmu": fmu,
        "fmu_sha256": fmu_sha256,
        "packages": package_versions(),
        "residual": residual,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "config": experiment.model_dump(mode="json", exclude={"source"}),
    }


def _resume(run_dir: Path, overrides: dict[str, Any], progress: bool) -> TrainResult:
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.policies import load_model

    info_file = run_dir / "run.json"
    if not info_file.is_file() or not (run_dir / "model.zip").is_file():
        raise ConfigError(
            f"--resume {run_dir}: not a run directory (expected run.json and model.zip from "
            "`fmu-bridge train`)"
        )
    info = json.loads(info_file.read_text())
    experiment_path = run_dir / "experiment.yaml"
    experiment = load_experiment(experiment_path, version=info["version"])
    given = {k: v for k, v in overrides.items() if v is not None}  # unset options keep the run's values
    try:
        settings = TrainingSettings.model_validate({**info["settings"], **given})
    except ValidationError as exc:
        raise ConfigError(f"--resume {run_dir}: invalid training settings: {exc}") from None
    env = build_vec_env(settings, experiment, experiment_path, info.get("residual"), settings.seed + 1)
    if (run_dir / "vecnormalize.pkl").is_file():
        env = VecNormalize.load(str(run_dir / "vecnormalize.pkl"), env)
    model = load_model(run_dir / "model.zip", info["algo"])
    model.set_env(env)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(run_dir / "logs"), ["csv", "tensorboard", "log"]))
    info.setdefault("resumed", []).append({"at": int(model.num_timesteps), "timesteps": settings.timesteps})
    return _learn(model, settings.timesteps, None, run_dir, info, progress=progress, reset=False)
