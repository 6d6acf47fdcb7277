"""Agents for evaluation: trained SB3 models and baselines, all behind one small interface.

A policy sees the observation (as the agent does) and the task's named signals in physical
units (outputs, inputs, references), so a PID controller is configured by variable names.
Baselines compute physical input values and act through the task's action space
(``Task.action_for_inputs``), so they run in exactly the env an agent runs in.
"""

from __future__ import annotations

import copy
import importlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from agents.run_state import read_run
from agents.runtime import OnnxPolicy
from bridge.errors import ConfigError
from bridge.task.core import Task
from bridge.task.fixed import physical_action, start_values, zero_values

if TYPE_CHECKING:
    from bridge.experiment.config import Experiment

_log = logging.getLogger(__name__)

ALGOS = ("PPO", "SAC", "TD3", "A2C", "DQN")


class Policy(Protocol):
    name: str

    def reset(self, task: Task, seed: int | None) -> None: ...

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any: ...


def episode_stats(policy: Policy) -> dict[str, float]:
    """A policy's own counts over the episode since its reset (an mpc's solver fallbacks, samples a
    command limiter held back); they join the episode's metrics. Empty for most policies."""
    stats = getattr(policy, "episode_stats", None)
    return dict(stats()) if callable(stats) else {}


class PidSpec(BaseModel):
    """A discrete PID controller on one output/reference pair driving one input."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    type: str = "pid"
    output: str
    reference: str
    input: str
    kp: float = 1.0
    ki: float = 0.0
    kd: float = 0.0
    limits: tuple[float, float] | None = None
    anti_windup: str = Field(default="clamp", pattern="^(clamp|back_calculation|none)$")
    tracking_time_s: float | None = None
    feedforward: float = 0.0
    feedforward_gains: dict[str, float] = {}


class Pid:
    """u = ff + kp e + ki sum(e dt) + kd de/dt, saturated to ``limits``, with anti-windup.

    The feed-forward ff is ``feedforward`` plus ``feedforward_gains[name] * signal`` for each named
    task signal (e.g. a steering angle from the path curvature: gain = wheelbase in m).

    ``clamp`` freezes the integrator while the output saturates in the direction of the error;
    ``back_calculation`` bleeds the saturation excess back into the integrator with time
    constant ``tracking_time_s`` (default sqrt(Ti*Td), or Ti without a D part).
    """

    def __init__(self, spec: PidSpec, name: str = "pid") -> None:
        self.spec, self.name = spec, name
        self._dt = 0.0
        self._integral = 0.0
        self._previous: float | None = None

    def reset(self, task: Task, seed: int | None) -> None:
        roles = [(self.spec.output, "output"), (self.spec.reference, "reference")]
        roles += [(key, "feed-forward signal") for key in self.spec.feedforward_gains]
        for key, role in roles:
            if key not in task.signal_names:
                raise ConfigError(
                    f"baseline {self.name}: {role} {key!r} is not a signal of the task; "
                    f"signals: {list(task.signal_names)}"
                )
        if self.spec.input not in task.action_inputs:
            raise ConfigError(
                f"baseline {self.name}: input {self.spec.input!r} is not an action input "
                f"{list(task.action_inputs)}"
            )
        self._task = task
        self._index = task.action_inputs.index(self.spec.input)
        self._dt = task.timing.sampling_time_s
        self._integral, self._previous = 0.0, None

    def control(self, signals: Mapping[str, float]) -> float:
        s = self.spec
        error = signals[s.reference] - signals[s.output]
        derivative = 0.0 if self._previous is None else (error - self._previous) / self._dt
        self._previous = error
        feedforward = s.feedforward + sum(k * signals[name] for name, k in s.feedforward_gains.items())
        unsaturated = feedforward + s.kp * error + self._integral + s.kd * derivative
        u = unsaturated if s.limits is None else float(np.clip(unsaturated, *s.limits))
        step = s.ki * error * self._dt
        if s.anti_windup == "clamp":
            saturating = u != unsaturated and np.sign(error) == np.sign(unsaturated - u)
            if not saturating:
                self._integral += step
        elif s.anti_windup == "back_calculation" and s.ki:
            tracking = s.tracking_time_s or (np.sqrt((s.kp / s.ki) * (s.kd / s.kp)) if s.kd else s.kp / s.ki)
            self._integral += step + (u - unsaturated) * self._dt / tracking
        else:
            self._integral += step
        return u

    def inputs(self, signals: Mapping[str, float]) -> list[float]:
        """Physical values of every action input: the controlled one from the PID, the rest as they are."""
        inputs = [signals[name] for name in self._task.action_inputs]
        inputs[self._index] = self.control(signals)
        return inputs

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        return self._task.action_for_inputs(self.inputs(signals))


class ModelBased:
    """An ``lqr`` or ``mpc`` baseline: designed from the FMU linearised through model exchange
    (``bridge.control``), once per policy, at the first reset."""

    def __init__(self, kind: str, design: Mapping[str, Any], name: str) -> None:
        from bridge.experiment.control import ControlDesign

        self.kind, self.name = kind, name
        self.design = ControlDesign.model_validate(design)
        self.controller: Any = None
        self._experiment: Any = None

    def reset(self, task: Task, seed: int | None) -> None:
        if self.controller is None or self._experiment is not task.experiment:
            from bridge.control.controller import LinearController

            cls: Any = LinearController
            if self.kind == "mpc":
                from bridge.control.mpc import Mpc

                cls = Mpc
            stray = [n for n in self.design.inputs if n not in task.action_inputs]
            if stray:
                raise ConfigError(
                    f"baseline {self.name}: inputs {stray} are not action inputs {list(task.action_inputs)}"
                )
            controller = cls(self.design, task.experiment, task.timing.sampling_time_s, self.name)
            controller.check_signals(task.signal_names)
            mapping = task.action_mapping
            limits = {}
            if mapping.kind == "continuous":
                limits = {
                    n: (c - h, c + h) for n, c, h in zip(task.action_inputs, mapping.centre, mapping.half)
                }
            controller.build(limits)
            self.controller, self._experiment = controller, task.experiment
        self._task = task
        self._index = [task.action_inputs.index(n) for n in self.design.inputs]
        self.controller.reset()
        self._failures_at_reset = self.controller.failures

    def episode_stats(self) -> dict[str, float]:
        """``rate_limited``: samples whose command the rate limit held back; an mpc's
        ``solver_fallbacks``: samples where OSQP gave no solution and the lqr law acted."""
        stats = {"rate_limited": float(self.controller.rate_limited)}
        if self.kind == "mpc":
            stats["solver_fallbacks"] = float(self.controller.failures - self._failures_at_reset)
        return stats

    def inputs(self, signals: Mapping[str, float]) -> list[float]:
        inputs = [signals[name] for name in self._task.action_inputs]
        for i, value in zip(self._index, self.controller.control(signals)):
            inputs[i] = value
        return inputs

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        return self._task.action_for_inputs(self.inputs(signals))


def discrete_levels(task: Task) -> dict[str, list[float]] | None:
    """The levels each action input can take on a discrete space (None if continuous)."""
    actions = task.experiment.actions
    if actions.type == "continuous":
        return None
    if actions.type == "discrete" and actions.table:
        return {
            name: sorted({float(row[i]) for row in actions.table}) for i, name in enumerate(actions.inputs)
        }
    return {name: [float(v) for v in actions.levels[name]] for name in actions.inputs}


@dataclass
class FixedPolicy:
    """``zero`` (no change: 0 on every FMU input, the start value on every tunable parameter) /
    ``start`` (the model as exported: every input at its start value, parameters untouched) /
    ``constant:V`` (the physical value V) / ``random`` (seeded samples of the action space).

    On a continuous space the physical values reach the FMU exactly (float64, not through the
    agent's float32 action), clipped to an input's bounds with one warning
    (:mod:`bridge.task.fixed`). On a discrete space the value must be one of the levels: ``zero``
    on a push-left/push-right cart-pole would otherwise push at the nearest level every step while
    being called zero; ``start`` goes to the level nearest each start value, with a warning where
    that is not the start value. A model without actions takes only ``zero`` and ``start``.
    """

    name: str
    value: float | None = None
    zero: bool = False
    start: bool = False
    _built_for: Task | None = field(default=None, init=False, repr=False, compare=False)

    def reset(self, task: Task, seed: int | None) -> None:
        if self.value is not None and task is self._built_for:
            return  # the same action for every episode (and its warning once)
        self._task = task
        if self.start:
            self._action = (
                physical_action(task, start_values(task), f"agent {self.name!r}")
                if task.action_inputs
                else task.action_for_inputs([])
            )
            self._built_for = task
            return
        if not task.action_inputs and not self.zero:
            raise ConfigError(
                f"agent {self.name!r}: the experiment has no actions (actions.inputs is empty), so "
                "there is nothing to apply it to; evaluate zero instead, or add an FMU input or "
                "tunable parameter to actions.inputs"
            )
        if self.value is not None:
            if task.action_mapping.kind == "continuous" and task.action_inputs:
                values = zero_values(task) if self.zero else [self.value] * len(task.action_inputs)
                self._action = physical_action(task, values, f"agent {self.name!r}")
                self._built_for = task
                return
            self._check_level(task, self.value)
            self._action = task.action_for_inputs([self.value] * len(task.action_inputs))
        else:  # its own copy: policies sharing the task's space must not share its generator
            self._space = copy.deepcopy(task.action_space)
            self._space.seed(seed)

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        return self._action if self.value is not None else self._space.sample()

    def _check_level(self, task: Task, value: float) -> None:
        levels = discrete_levels(task)
        missing = {n: v for n, v in (levels or {}).items() if value not in v}
        if missing:
            what = "zero input" if value == 0 else f"{value:g}"
            raise ConfigError(
                f"agent {self.name!r}: this discrete action space has no action applying {what}: "
                f"levels {missing}; use constant:LEVEL with one of the levels (named by what it applies)"
            )


@dataclass
class PythonPolicy:
    """Any callable ``fn(obs, signals) -> action`` given as ``module:function``."""

    name: str
    fn: Callable[[Any, Mapping[str, float]], Any]

    def reset(self, task: Task, seed: int | None) -> None:
        reset = getattr(self.fn, "reset", None)
        if callable(reset):
            reset(task, seed)

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        return self.fn(obs, signals)


class Sb3Policy:
    """A trained model, deterministic, with the VecNormalize observation statistics it was trained with."""

    def __init__(self, path: Path, name: str | None = None) -> None:
        self.path = path
        run_dir = path if path.is_dir() else path.parent
        self.run = read_run(run_dir)
        _check_status(self.run, run_dir, has_model=not path.is_dir() or _has_model(path))
        model_file = _model_file(path)
        self.name = name or (run_dir.name if path.is_dir() else path.stem)
        algo = self.run.get("algo")
        self.model = load_model(model_file, algo)
        self._obs_rms = None
        stats = run_dir / "vecnormalize.pkl"
        if stats.is_file():
            import pickle

            with stats.open("rb") as handle:
                normalizer = pickle.load(handle)
            self._obs_rms, self._clip, self._eps = normalizer.obs_rms, normalizer.clip_obs, normalizer.epsilon
        self.residual: dict[str, Any] | None = self.run.get("residual")
        self._baseline: Policy | None = None

    def reset(self, task: Task, seed: int | None) -> None:
        self._task = task
        if self.residual:
            self._baseline = baseline_from_run(self.residual, task.experiment)
            self._baseline.reset(task, seed)

    def normalise(self, obs: Any) -> Any:
        if self._obs_rms is None:
            return obs
        return np.clip(
            (obs - self._obs_rms.mean) / np.sqrt(self._obs_rms.var + self._eps), -self._clip, self._clip
        )

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        action, _ = self.model.predict(self.normalise(obs), deterministic=True)
        if self._baseline is not None and self.residual is not None:
            return combine(self._task, self._baseline, signals, action, float(self.residual["scale"]))
        return action


def rllib_run(run_dir: Path) -> bool:
    """True for a run folder written by ``train --engine rllib``."""
    return read_run(run_dir).get("engine") == "rllib" if run_dir.is_dir() else False


def _model_file(path: Path) -> Path:
    if path.is_file():
        return path
    if rllib_run(path):
        raise ConfigError(
            "this run was trained with --engine rllib: it has no stable-baselines3 model; deploy its "
            "ONNX export with --runtime onnx (training writes policy.onnx; `fmu-bridge agent export "
            f"onnx RUN` writes it again) [{path}]"
        )
    for name in ("best_model.zip", "model.zip"):
        if (path / name).is_file():
            return path / name
    raise ConfigError(
        f"{path} holds no model: expected best_model.zip or model.zip (a run directory from "
        "`fmu-bridge train`) or a .zip saved by stable-baselines3"
    )


def _has_model(run_dir: Path) -> bool:
    return any((run_dir / name).is_file() for name in ("best_model.zip", "model.zip"))


def _check_status(run: Mapping[str, Any], run_dir: Path, *, has_model: bool = True) -> None:
    """Refuse a run whose training failed, or that ended before it saved a model; say so for one
    interrupted (stopped, or its process killed) or still training."""
    status = run.get("status")
    if status == "failed":
        raise ConfigError(
            f"the training of run {run_dir.name} failed ({run.get('error', 'no error recorded')}), so "
            "its model is not a trained agent; fix the cause and train again, or continue it with "
            f"`fmu-bridge train --resume` [{run_dir}]"
        )
    how = run.get("status_detail", "it was stopped")
    if status == "interrupted" and not has_model:
        raise ConfigError(
            f"run {run_dir.name} was interrupted before it saved a model ({how}); continue it from "
            f"its newest checkpoint with `fmu-bridge train --resume`, or train again [{run_dir}]"
        )
    if status == "interrupted":
        _log.warning(
            "run %s was interrupted after %s timesteps (%s): its model is only partly trained",
            run_dir.name,
            run.get("timesteps", "?"),
            how,
        )
    elif status == "running":
        _log.warning(
            "run %s is still training (its process is alive): the model may be untrained or partly trained",
            run_dir.name,
        )


def load_model(path: Path, algo: str | None) -> Any:
    """Load an SB3 model; without a known algorithm, try each one."""
    import stable_baselines3 as sb3

    candidates = [algo] if algo else list(ALGOS)
    errors = []
    for name in candidates:
        try:
            return getattr(sb3, name).load(str(path), device="cpu")
        except Exception as exc:  # a wrong algorithm class fails while loading its parameters
            errors.append(f"{name}: {exc}")
    raise ConfigError(f"cannot load {path} as a stable-baselines3 model ({'; '.join(errors)[:400]})")


def make_policy(spec: str, experiment_baselines: Mapping[str, Any], *, name: str | None = None) -> Policy:
    """An agent from a command-line word: a model path or run dir, ``zero``, ``random``,
    ``constant:V``, a baseline named in ``evaluation.baselines``, or ``python:module:function``."""
    if spec in experiment_baselines:
        return baseline(spec, experiment_baselines[spec])
    if spec == "zero":
        return FixedPolicy(name or "zero", 0.0, zero=True)
    if spec == "start":
        return FixedPolicy(name or "start", 0.0, start=True)
    if spec == "random":
        return FixedPolicy(name or "random")
    if spec.startswith("constant:"):
        try:
            return FixedPolicy(name or spec, float(spec.partition(":")[2]))
        except ValueError:
            raise ConfigError(f"agent {spec!r}: expected constant:NUMBER") from None
    if spec.startswith("python:"):
        return PythonPolicy(name or spec, _import(spec.partition(":")[2], spec))
    path = Path(spec)
    if rllib_run(path):  # trained on RLlib: its ONNX export acts
        return OnnxPolicy(path, name or path.name)
    if path.exists():
        return Sb3Policy(path, name)
    raise ConfigError(
        f"agent {spec!r} is not a model file or run directory, not a baseline of the experiment "
        f"({sorted(experiment_baselines) or 'none defined'}), and not zero, start, random, constant:V or "
        "python:module:function"
    )


def baseline(name: str, config: Mapping[str, Any]) -> Policy:
    kind = config.get("type", "pid")
    if kind == "pid":
        return Pid(PidSpec.model_validate(config), name)
    if kind in ("lqr", "mpc"):
        return ModelBased(kind, config["design"], name)
    if kind == "constant":
        return FixedPolicy(name, float(config["value"]))
    if kind == "python":
        return PythonPolicy(name, _import(str(config["callable"]), f"evaluation.baselines.{name}"))
    raise ConfigError(
        f"evaluation.baselines.{name}: type {kind!r} is unknown; use pid, lqr, mpc, constant or python"
    )


def load_policy(path: Path, runtime: str, experiment: Any = None) -> Any:
    """The deployed policy of a run: ``torch`` (stable-baselines3), ``onnx`` (onnxruntime), ``fmu``
    (the exported policy FMU), or ``baseline``: ``path`` names one of the experiment's
    ``evaluation.baselines`` (pid, lqr, mpc)."""
    if runtime == "baseline":
        baselines = experiment.evaluation.baselines if experiment is not None else {}
        if str(path) not in baselines:
            raise ConfigError(
                f"--runtime baseline: {str(path)!r} is not in evaluation.baselines of the experiment "
                f"({sorted(baselines) or 'none defined'}); pass the experiment with --config"
            )
        return baseline(str(path), baselines[str(path)].settings())
    if runtime == "onnx":
        return OnnxPolicy(path)
    if runtime == "fmu":
        from agents.export.fmu_runner import FmuAgentPolicy

        return FmuAgentPolicy(path)
    if runtime == "torch":
        return Sb3Policy(path)
    raise ConfigError(f"--runtime {runtime!r} is unknown; use torch, onnx, fmu or baseline")


Baseline = Pid | ModelBased


def physical_inputs(baseline: Baseline, task: Task, signals: Mapping[str, float]) -> list[float]:
    del task
    return baseline.inputs(signals)


def combine(task: Task, baseline: Any, signals: Mapping[str, float], residual: Any, scale: float) -> Any:
    """The env action for baseline inputs plus ``scale`` times the residual action."""
    base = np.asarray(physical_inputs(baseline, task, signals))
    return task.action_for_inputs(base + scale * np.clip(np.asarray(residual, dtype=np.float64), -1.0, 1.0))


def baseline_from_run(residual: Mapping[str, Any], experiment: Experiment) -> Baseline:
    del experiment
    return residual_baseline(residual)


def residual_baseline(residual: Mapping[str, Any]) -> Baseline:
    made = baseline(str(residual["baseline"]), residual["config"])
    assert isinstance(made, (Pid, ModelBased))
    return made


def _import(path: str, key: str) -> Callable[..., Any]:
    module, _, attr = path.partition(":")
    try:
        fn = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{key}: cannot import {path!r} ({exc})") from exc
    if not callable(fn):
        raise ConfigError(f"{key}: {path!r} is not callable")
    return fn  # type: ignore[no-any-return]
