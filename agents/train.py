"""Training with stable-baselines3 from an experiment file: ``fmu-bridge train``.

A run directory holds everything needed to reproduce and reuse the run: the experiment file
as it was, the resolved training settings, the FMU checksum, package versions and seed
(``run.json``), the final and best models, checkpoints, VecNormalize statistics, CSV and
TensorBoard logs. ``--resume RUN`` continues a run's step count.
"""

from __future__ import annotations

import contextlib
import json
import logging
import shutil
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from pydantic import ValidationError

from agents.checkpoints import (
    atomic_checkpoints,
    load_newest,
    resume_candidates,
    save_atomically,
    write_run_info,
)
from agents.run_state import GONE, training_lock
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


class ScenarioCycle(gym.Wrapper):
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
    settings: TrainingSettings,
    experiment: Experiment,
    path: Path,
    run_dir: Path | None,
    *,
    fmu: str = "absolute",
) -> Path:
    if run_dir is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        from bridge.recording.env_recorder import slug

        run_dir = Path("runs") / slug(
            f"{experiment.name}-{experiment.version}-{settings.algo.lower()}-{stamp}"
        )
    if run_dir.exists() and any(run_dir.iterdir()):
        raise ConfigError(
            f"run directory {run_dir} exists and is not empty; choose another --run-dir or --resume it"
        )
    run_dir.mkdir(parents=True, exist_ok=True)
    write_run_experiment(path, run_dir, fmu=fmu)
    return run_dir


_PATH_KEYS = ("fmu", "file", "state_file")  # model.fmu, system.components.*.fmu, csv profiles, state files


def write_run_experiment(path: Path, run_dir: Path, *, fmu: str = "absolute") -> Path:
    """The run folder's copy of the experiment at ``path``, self-contained: every relative file it
    names (the FMU, system components, csv profiles) is rewritten as an absolute path, so the run
    resumes, evaluates and deploys from any folder. With ``fmu="copy"`` the model's FMU is copied
    into the run folder and named by its file name instead (the run then outlives the original).

    The text is kept (comments and all) with only those values replaced; where a value cannot be
    replaced in place, the data is written out without the comments.
    """
    if fmu not in ("absolute", "copy"):
        raise ConfigError(f"--fmu {fmu!r}: expected absolute or copy")
    import yaml

    text = path.read_text()
    data = yaml.safe_load(text)
    base = path.resolve().parent
    replace: dict[str, str] = {}
    for spec in _relative_paths(data):
        replace[spec] = str((base / Path(spec).expanduser()).resolve())
    model = data.get("model") if isinstance(data, dict) else None
    model_fmu = model.get("fmu") if isinstance(model, dict) else None
    if fmu == "copy" and isinstance(model_fmu, str) and not model_fmu.startswith("example:"):
        source = Path(replace.get(model_fmu, model_fmu)).expanduser()
        if not source.is_file():
            raise ConfigError(
                f"--fmu copy: model.fmu {model_fmu!r} is not a file (looked at {source}) [{path}]"
            )
        shutil.copy(source, run_dir / source.name)
        replace[model_fmu] = source.name
    policy = model.get("reset_policy") if isinstance(model, dict) else None
    saved = policy.get("state_file") if isinstance(policy, dict) else None
    if fmu == "copy" and isinstance(saved, str):  # the state file travels with the FMU it belongs to
        source = Path(replace.get(saved, saved)).expanduser()
        if source.is_file():
            shutil.copy(source, run_dir / source.name)
            replace[saved] = source.name
    for spec, new in replace.items():
        text = _with_value(text, spec, new)
    if yaml.safe_load(text) != _substituted(data, replace):
        header = f"# {path.name} with its file paths made absolute (comments were not kept)\n"
        text = header + yaml.safe_dump(_substituted(data, replace), sort_keys=False)
    target = run_dir / "experiment.yaml"
    target.write_text(text)
    return target


def _with_value(text: str, spec: str, new: str) -> str:
    """``text`` with the YAML value ``spec`` of a path key (plain or quoted) replaced by ``new``."""
    import re

    keys = "|".join(_PATH_KEYS)
    pattern = rf"(?m)((?:^|[\s{{,])(?:{keys}):\s*)(['\"]?){re.escape(spec)}\2(?=\s*(?:[,}}#]|$))"
    replacement = json.dumps(new)
    return re.sub(pattern, lambda m: m.group(1) + replacement, text)


def _relative_paths(data: Any) -> list[str]:
    found: list[str] = []
    if isinstance(data, dict):
        for key, value in data.items():
            if key in _PATH_KEYS and isinstance(value, str) and _is_relative_file(value):
                found.append(value)
            else:
                found += _relative_paths(value)
    elif isinstance(data, list):
        for item in data:
            found += _relative_paths(item)
    return found


def _is_relative_file(spec: str) -> bool:
    return not spec.startswith("example:") and not Path(spec).expanduser().is_absolute()


def _substituted(data: Any, replace: dict[str, str]) -> Any:
    if isinstance(data, dict):
        return {
            k: replace.get(v, v) if k in _PATH_KEYS and isinstance(v, str) else _substituted(v, replace)
            for k, v in data.items()
        }
    if isinstance(data, list):
        return [_substituted(item, replace) for item in data]
    return data


def train(
    experiment_path: Path | None,
    *,
    overrides: dict[str, Any] | None = None,
    run_dir: Path | None = None,
    resume: Path | None = None,
    version: str | None = None,
    progress: bool = True,
    fmu: str = "absolute",
) -> TrainResult:
    """Train an agent; returns where everything went. The run folder's experiment names its files
    by absolute path, or (``fmu="copy"``) holds a copy of the FMU (see :func:`write_run_experiment`)."""
    with terminate_interrupts():
        if resume is not None:
            return _resume(resume, overrides or {}, progress)
        return _train_new(experiment_path, overrides, run_dir, version=version, progress=progress, fmu=fmu)


class Terminated(KeyboardInterrupt):
    """SIGTERM during training: handled as Ctrl-C is (the model so far saved, ``interrupted``)."""


@contextlib.contextmanager
def terminate_interrupts() -> Iterator[None]:
    """While training in the main thread, SIGTERM (``kill``, a scheduler's stop) interrupts it the
    way Ctrl-C does: a checkpoint of the model so far and ``status: interrupted`` in run.json."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: Any) -> None:
        raise Terminated(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _train_new(
    experiment_path: Path | None,
    overrides: dict[str, Any] | None,
    run_dir: Path | None,
    *,
    version: str | None,
    progress: bool,
    fmu: str,
) -> TrainResult:
    if experiment_path is None:
        raise ConfigError("train: give an experiment file, or resume= a run directory")
    experiment = load_experiment(experiment_path, version=version)
    refuse_untrainable(experiment)
    settings = TrainingSettings.from_experiment(experiment, overrides or {})
    residual = _residual(experiment, settings)
    run_dir = prepare_run_dir(settings, experiment, experiment_path, run_dir, fmu=fmu)
    info = _run_info(settings, experiment, residual)
    with training_lock(run_dir), _marked(run_dir, info):
        write_run_info(run_dir, info)
        return _train_in(
            run_dir,
            info,
            settings=settings,
            experiment=experiment,
            experiment_path=experiment_path,
            residual=residual,
            progress=progress,
        )


def refuse_untrainable(experiment: Experiment) -> None:
    """A ConfigError (exit 2) for an experiment no agent can learn from: nothing to act on."""
    where = f" [{experiment.source}]" if experiment.source else ""
    if not experiment.actions.inputs:
        raise ConfigError(
            "train: the experiment has no actions (actions.inputs is empty), so there is nothing for "
            "an agent to learn; add an FMU input or a tunable parameter to actions.inputs (see "
            "`fmu-bridge inspect` for the FMU's inputs), or use `fmu-bridge simulate` to run an "
            f"observation-only experiment{where}"
        )
    # an empty observation is refused by the experiment's own validation (observations: ...)


@contextlib.contextmanager
def _marked(run_dir: Path, info: dict[str, Any]) -> Iterator[None]:
    """run.json says ``failed`` (with the error) or ``interrupted`` when training does not finish."""
    try:
        yield
    except KeyboardInterrupt:
        info["status"] = "interrupted"
        write_run_info(run_dir, info)
        raise
    except BaseException as exc:
        info["status"] = "failed"
        info["error"] = f"{type(exc).__name__}: {exc}"
        write_run_info(run_dir, info)
        raise


def _train_in(
    run_dir: Path,
    info: dict[str, Any],
    *,
    settings: TrainingSettings,
    experiment: Experiment,
    experiment_path: Path,
    residual: dict[str, Any] | None,
    progress: bool,
) -> TrainResult:
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

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
    callbacks = _callbacks(settings, eval_env, run_dir)
    return _learn(model, settings.timesteps, callbacks, run_dir, info, progress=progress, reset=True)


def _callbacks(settings: TrainingSettings, eval_env: Any, run_dir: Path) -> Any:
    """Checkpoints and periodic evaluation; the best evaluated model goes to ``best_model.zip``.

    A resumed run carries on with the evaluations it has (``evaluations.npz``): ``best_model.zip``
    is replaced only by a model that evaluates better than the best one so far."""
    import numpy as np
    from stable_baselines3.common.callbacks import CallbackList, EvalCallback

    per_env = max(1, settings.n_envs)
    evaluation = EvalCallback(
        eval_env,
        n_eval_episodes=settings.eval_episodes,
        eval_freq=max(settings.eval_every // per_env, 1),
        best_model_save_path=str(run_dir),
        log_path=str(run_dir),
        deterministic=True,
        verbose=0,
    )
    earlier = run_dir / "evaluations.npz"
    if earlier.is_file():
        with np.load(earlier) as data:
            evaluation.evaluations_timesteps = [int(t) for t in data["timesteps"]]
            evaluation.evaluations_results = [list(r) for r in data["results"]]
            evaluation.evaluations_length = [list(n) for n in data["ep_lengths"]]
        if evaluation.evaluations_results:
            evaluation.best_mean_reward = max(float(np.mean(r)) for r in evaluation.evaluations_results)
    checkpoints = atomic_checkpoints(
        max(settings.checkpoint_steps // per_env, 1),
        run_dir / "checkpoints",
        save_vecnormalize=bool(settings.normalize),
    )
    return CallbackList([checkpoints, evaluation])


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
    from stable_baselines3.common.callbacks import CallbackList

    from agents.progress import announce, train_progress
    from agents.threads import use_threads_for

    use_threads_for(model.policy)  # one thread for a small policy: torch's pool spins against the envs
    start = time.perf_counter()
    info["status"] = "running"
    write_run_info(run_dir, info)
    really = announce(model, timesteps)
    if progress:
        bar = train_progress(really)
        callbacks = CallbackList([callbacks, bar]) if callbacks is not None else bar
    try:
        model.learn(
            total_timesteps=timesteps, callback=callbacks, progress_bar=False, reset_num_timesteps=reset
        )
        info["status"] = "done"
    except KeyboardInterrupt:
        info["status"] = "interrupted"
        _log.warning("training interrupted: saving the model so far")
    except BaseException as exc:
        info["status"] = "failed"
        info["error"] = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        wall = time.perf_counter() - start
        info["wall_time_s"] = info.get("wall_time_s", 0.0) + wall
        info["timesteps"] = int(model.num_timesteps)
        save_atomically(model.save, run_dir / "model.zip")
        env = model.get_env()
        if env is not None and hasattr(env, "save") and hasattr(env, "obs_rms"):
            save_atomically(lambda path: env.save(str(path)), run_dir / "vecnormalize.pkl")
        write_run_info(run_dir, info)
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
        "status": "starting",  # from the first write on: a run killed before its first step says so
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
    info_file = run_dir / "run.json"
    if not info_file.is_file():
        raise ConfigError(
            f"--resume {run_dir}: not a run directory (expected run.json from `fmu-bridge train`)"
        )
    with training_lock(run_dir):
        return _resume_held(run_dir, json.loads(info_file.read_text()), overrides, progress)


def _resume_held(
    run_dir: Path, info: dict[str, Any], overrides: dict[str, Any], progress: bool
) -> TrainResult:
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.policies import load_model

    _mark_gone(run_dir, info)
    model, _, stats_file = load_newest(
        run_dir, lambda path: load_model(path, info["algo"]), resume_candidates(run_dir)
    )
    experiment_path = run_dir / "experiment.yaml"
    experiment = load_experiment(experiment_path, version=info["version"])
    given = {k: v for k, v in overrides.items() if v is not None}  # unset options keep the run's values
    try:
        settings = TrainingSettings.model_validate({**info["settings"], **given})
    except ValidationError as exc:
        raise ConfigError(f"--resume {run_dir}: invalid training settings: {exc}") from None
    residual = info.get("residual")
    env = build_vec_env(settings, experiment, experiment_path, residual, settings.seed + 1)
    eval_env = build_eval_env(env, settings, experiment, experiment_path, residual)
    if stats_file is not None:
        env = VecNormalize.load(str(stats_file), env)
        eval_env = VecNormalize(  # its statistics follow the training env's at each evaluation
            eval_env, training=False, norm_reward=False, **settings.normalize_kwargs(eval_env=True)
        )
    model.set_env(env)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(run_dir / "logs"), ["csv", "tensorboard", "log"]))
    info.setdefault("resumed", []).append({"at": int(model.num_timesteps), "timesteps": settings.timesteps})
    callbacks = _callbacks(settings, eval_env, run_dir)
    return _learn(model, settings.timesteps, callbacks, run_dir, info, progress=progress, reset=False)


def _mark_gone(run_dir: Path, info: dict[str, Any]) -> None:
    """A run whose run.json still says ``running`` or ``starting`` lost its process (we hold the
    lock now): it was interrupted."""
    if info.get("status") in ("running", "starting"):
        info["status"] = "interrupted"
        _log.warning("run %s was interrupted: %s; resuming it", run_dir.name, GONE)
