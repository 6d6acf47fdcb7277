"""Batched envs: N episodes of one experiment over a ``BatchPlant`` and a ``BatchTask``.

``BatchEnv`` is the engine (one native call steps every FMU instance, the Task's math runs
with numpy over the batch; a batch of one runs the scalar Task, ``FmuEnv``'s own code, on
lists instead, which costs less than numpy for one row); two interfaces sit on it:

- :class:`BatchVectorEnv`, a Gymnasium ``VectorEnv`` in either autoreset mode, declared in its
  ``metadata["autoreset_mode"]``: SAME_STEP (the default) resets an env whose episode ended in
  the same step, its last observation and info in ``infos["final_obs"]`` / ``infos["final_info"]``
  (masks ``_final_obs`` / ``_final_info``); NEXT_STEP (gymnasium's default, what RLlib's env
  runner assumes) returns the last observation itself and resets that env on the next step,
  which ignores its action and returns the first observation, reward 0, not done;
- :class:`BatchVecEnv`, stable-baselines3's ``VecEnv`` interface (``terminal_observation`` and
  ``TimeLimit.truncated`` in ``infos[i]``), registered as a virtual subclass of SB3's ``VecEnv``
  whenever SB3 is loaded (bridge never imports SB3).

Env ``i`` draws from its own generator, seeded ``seed + i`` by ``reset(seed=seed)``, exactly as
an ``FmuEnv`` reset with that seed: the trajectories are bit-identical. A failed FMU step or
non-finite outputs end that env's episode only (``on_error="truncate"``, the default: the error
in its info's ``plant_error``, the episode truncated and reset); ``on_error="raise"`` raises it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from bridge.env.autoreset import OnError, env_scenarios, on_error_mode, refuse_same_step_under_rllib
from bridge.env.autoreset import autoreset_mode as _autoreset_mode
from bridge.env.autoreset import env_seeds as _seeds
from bridge.env.sb3_vec import Sb3VecEnv
from bridge.errors import BridgeError, ConfigError, StepError
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.validate import check_experiment, resolve_fmu
from bridge.fmu import read_model_info
from bridge.plant.batch import BatchPlant
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.task.batch import BatchTask
from bridge.task.core import NonFiniteOutputs

_log = logging.getLogger(__name__)
ObsArray = npt.NDArray[np.float32]


class BatchEnv:
    """``n_envs`` episodes of ``experiment``, stepped together (the engine of both interfaces).

    Args:
        experiment: an :class:`Experiment` or the path of an experiment YAML file.
        n_envs: how many envs (FMU instances).
        version: the env version to use.
        threads: native threads stepping the FMUs.
        native: force (True) or forbid (False) the native stepper; None: where possible.
        on_error: ``"truncate"`` (default) or ``"raise"`` when one env's model fails.
        autoreset: reset an env whose episode ended in the same step; else it stops stepping
            (``active[i]`` False) until ``reset_one`` (evaluation runs one episode per env).
    """

    def __init__(
        self,
        experiment: Experiment | str | Path,
        n_envs: int,
        *,
        version: str | None = None,
        threads: int = 1,
        native: bool | None = None,
        on_error: OnError = "truncate",
        autoreset: bool = True,
    ) -> None:
        self.experiment = exp = as_experiment(experiment, version)
        self.n, self.on_error, self.autoreset = n_envs, on_error_mode(on_error), autoreset
        self.active = np.ones(n_envs, dtype=bool)
        _check_once_per_process(exp, n_envs)
        self.plant = plant = BatchPlant(experiment_plant_spec(exp), n_envs, threads=threads, native=native)
        try:
            check_experiment(exp, plant.info)  # the task, once, against what the plant serves
            self.task = BatchTask(exp, plant.info.variables, plant.timing, n_envs)
            plant.bind(self.task.input_names, self.task.output_names)
        except BaseException:
            plant.close()
            raise
        self.rngs = [seeding.np_random()[0] for _ in range(n_envs)]
        self.samples = np.zeros(n_envs, dtype=np.int64)
        self.obs = np.zeros((n_envs, *self.task.observation_space.shape), dtype=np.float32)
        self.outputs = np.zeros((n_envs, len(self.task.output_names)))
        # one env: the scalar Task steps it (FmuEnv's own code, so the same results) on lists,
        # cheaper than numpy over a batch of one
        self._one = self.task.tasks[0] if n_envs == 1 else None
        self._codes = {reason: code for code, reason in enumerate(self.task.reasons)}
        self._discrete = self.task.tasks[0].action_mapping.kind == "discrete"

    def reset_one(self, i: int, seed: int | None = None, scenario: str | None = None) -> dict[str, Any]:
        """Start env ``i``'s next episode (``seed``: a fresh generator, as ``FmuEnv.reset``)."""
        if seed is not None:
            self.rngs[i] = seeding.np_random(seed)[0]
            self.task.tasks[i].sampler.restart()
        rng, task = self.rngs[i], self.task
        spec = task.new_episode(i, rng, scenario)
        outputs = self.plant.reset(i, spec.values, task.initial_inputs(i))
        try:
            self.obs[i] = task.first_observation(i, outputs.tolist(), rng)
        except NonFiniteOutputs as exc:
            raise self._non_finite(i, str(exc), step=0) from exc
        self.samples[i], self.active[i] = 0, True
        self.outputs[i] = outputs
        return {
            "time_s": self.plant.time_s(i),
            "step": 0,
            "scenario": spec.scenario,
            "drawn": dict(spec.drawn),
        }

    def reset_all(
        self, seeds: list[int | None], scenarios: list[str | None] | None = None
    ) -> tuple[ObsArray, list[dict[str, Any]]]:
        infos = [
            self._reset_or_recover(i, seeds[i], (scenarios or [None] * self.n)[i]) for i in range(self.n)
        ]
        return self.obs.copy(), infos

    def _reset_or_recover(
        self, i: int, seed: int | None = None, scenario: str | None = None
    ) -> dict[str, Any]:
        try:
            return self.reset_one(i, seed, scenario)
        except StepError as exc:
            if self.on_error == "raise":
                raise
            _log.warning("env %d: reset failed, trying once more: %s", i, exc)
            return {**self.reset_one(i, None, scenario), "plant_error": str(exc)}

    def step(
        self, actions: Any
    ) -> tuple[ObsArray, npt.NDArray[np.float64], Any, Any, dict[int, dict[str, Any]]]:
        """One step of every env; ends and resets episodes in the same step.

        Returns:
            obs (of the new episode where one ended), reward, terminated, truncated, and for
            each env whose episode ended: ``final_obs``, ``final_info`` and ``reset_info``.
        """
        if self._one is not None:
            if self.active[0]:
                return self._step_one(actions)
            return self._step_none()
        task, plant = self.task, self.plant
        inputs = task.actions_to_inputs(actions, self.samples)
        active = self.active.copy()
        result = plant.step(inputs, active)
        self.samples[active] += 1
        obs, reward, terminated, truncated, code, bad = task.step_result(
            result.outputs, self.samples, result.terminated
        )
        bad &= active
        terminated &= active
        truncated &= active
        errors = result.errors
        for i in np.flatnonzero(bad).tolist():
            if i not in errors:
                detail = str(task.tasks[i].bad_output(result.outputs[i].tolist(), int(self.samples[i])))
                errors[i] = self._non_finite(i, detail, step=int(self.samples[i]))
        return self._finish(
            result.outputs,
            obs=obs,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            code=code,
            errors=errors,
        )

    def _finish(
        self,
        outputs: npt.NDArray[np.float64],
        *,
        obs: ObsArray,
        reward: npt.NDArray[np.float64],
        terminated: Any,
        truncated: Any,
        code: Any,
        errors: Mapping[int, BridgeError],
    ) -> tuple[ObsArray, npt.NDArray[np.float64], Any, Any, dict[int, dict[str, Any]]]:
        """Truncate the episodes of failed envs (or raise), end and reset finished episodes."""
        if errors and self.on_error == "raise":
            raise errors[min(errors)]
        for i, error in errors.items():
            obs[i], reward[i], terminated[i], truncated[i] = self.obs[i], 0.0, False, True
            _log.warning("env %d: episode truncated by a plant error: %s", i, error)
        self.outputs[:] = outputs
        ended = (
            self._end_episodes(obs, terminated, truncated, code, errors)
            if errors or terminated.any() or truncated.any()
            else {}
        )
        self.obs = obs
        return obs, reward, terminated, truncated, ended

    def _step_none(self) -> tuple[ObsArray, npt.NDArray[np.float64], Any, Any, dict[int, dict[str, Any]]]:
        """``step`` of a batch of one whose episode ended and awaits ``reset_one``: nothing steps
        (its last observation, reward 0, not done)."""
        return self.obs.copy(), np.zeros(1), np.zeros(1, dtype=bool), np.zeros(1, dtype=bool), {}

    def _step_one(
        self, actions: Any
    ) -> tuple[ObsArray, npt.NDArray[np.float64], Any, Any, dict[int, dict[str, Any]]]:
        """``step`` of a batch of one, through the scalar Task (see ``_one``)."""
        task, plant, rng = self._one, self.plant, self.rngs[0]
        assert task is not None  # step() checked
        a = np.asarray(actions)
        sample = int(self.samples[0])
        batch = self.task  # its inputs, previous inputs and signals stay current (evaluation reads them)
        inputs = batch.inputs
        batch.previous[0] = inputs[0]
        action = a.reshape(1)[0] if self._discrete else a.reshape(1, -1)[0]
        try:
            inputs[0] = task.action_to_inputs(action, sample, rng)
        except BridgeError:
            raise self.task.bad_actions(actions, np.ones(1, dtype=bool)) from None  # the batch's words
        result = plant.step(inputs, self.active)
        self.samples[0] = sample = sample + 1
        errors: dict[int, BridgeError] = dict(result.errors)
        obs = np.empty_like(self.obs)
        reward = np.zeros(1)
        terminated, truncated, code = (
            np.zeros(1, dtype=bool),
            np.zeros(1, dtype=bool),
            np.zeros(1, dtype=np.int64),
        )
        if not errors:
            outputs = result.outputs[0].tolist()
            try:
                obs[0], reward[0], terminated[0], truncated[0], reason = task.step_result(
                    outputs, sample, bool(result.terminated[0]), rng
                )
                code[0] = self._codes[reason]
                batch.follow_scalar_step(self.samples)
            except NonFiniteOutputs:
                errors[0] = self._non_finite(0, str(task.bad_output(outputs, sample)), step=sample)
        if errors:  # rare: the signal rows the batch's own step leaves (evaluation reads them)
            batch.step_result(result.outputs, self.samples, result.terminated)
        return self._finish(
            result.outputs,
            obs=obs,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            code=code,
            errors=errors,
        )

    def _non_finite(self, i: int, detail: str, step: int) -> StepError:
        """Env ``i``'s model returned non-finite outputs: its instance is no longer ready (its next
        reset starts it again); the error to raise or to truncate its episode with."""
        self.plant.ready[i] = False
        return self.plant.failure(i, "the model returned non-finite outputs", detail, step=step)

    def _end_episodes(
        self, obs: ObsArray, terminated: Any, truncated: Any, code: Any, errors: Mapping[int, BridgeError]
    ) -> dict[int, dict[str, Any]]:
        ended: dict[int, dict[str, Any]] = {}
        reasons = self.task.reasons
        for i in np.flatnonzero(terminated | truncated).tolist():
            info: dict[str, Any] = {
                "time_s": self.plant.time_s(i),
                "step": int(self.samples[i]),
                "outputs": self.outputs[i].copy(),
                "reason": "plant_error" if i in errors else reasons[int(code[i])],
            }
            if i in errors:
                info["plant_error"] = str(errors[i])
            final_obs = obs[i].copy()
            if not self.autoreset:
                self.active[i] = False
                ended[i] = {"final_obs": final_obs, "final_info": info, "reset_info": {}}
                continue
            reset_info = self._reset_or_recover(i)
            obs[i] = self.obs[i]
            ended[i] = {"final_obs": final_obs, "final_info": info, "reset_info": reset_info}
        return ended

    def close(self) -> None:
        plant = getattr(self, "plant", None)
        if plant is not None:
            plant.close()


class BatchVectorEnv(VectorEnv[ObsArray, Any, Any]):
    """A Gymnasium ``VectorEnv`` over :class:`BatchEnv`.

    Args:
        experiment, n_envs, kwargs: as :class:`BatchEnv` (``autoreset`` follows the mode).
        autoreset_mode: ``AutoresetMode.SAME_STEP`` (default) or ``AutoresetMode.NEXT_STEP``
            (or their values ``"SameStep"`` / ``"NextStep"``); in ``metadata["autoreset_mode"]``.
            RLlib reads vector envs by NEXT_STEP rules: SAME_STEP built by RLlib is refused.

    ``infos`` holds per-env arrays ``step`` and ``time_s``. SAME_STEP: for envs whose episode
    ended, the last observation and info in ``final_obs`` / ``final_info`` and the new episode's
    reset info (``scenario``, ``drawn``) in ``reset_info`` (each with a ``_``-prefixed mask).
    NEXT_STEP: an env whose episode ended has its ``reason`` (and ``plant_error``, ``outputs``)
    in ``infos``; the step that resets it has its ``scenario`` and ``drawn``.
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        experiment: Experiment | str | Path,
        n_envs: int,
        *,
        autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP,
        **kwargs: Any,
    ) -> None:
        mode = _autoreset_mode(autoreset_mode)
        refuse_same_step_under_rllib(mode, "BatchVectorEnv")
        if "autoreset" in kwargs:
            raise ConfigError(
                "BatchVectorEnv takes autoreset_mode (SAME_STEP or NEXT_STEP), not autoreset; "
                "for episodes that stop at their end use BatchEnv(autoreset=False)"
            )
        self.engine = BatchEnv(experiment, n_envs, autoreset=mode is AutoresetMode.SAME_STEP, **kwargs)
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.num_envs = n_envs
        task = self.engine.task
        self.single_observation_space, self.single_action_space = task.observation_space, task.action_space
        self.observation_space = batch_space(task.observation_space, n_envs)
        self.action_space = batch_space(task.action_space, n_envs)
        self.render_mode = None
        self._to_reset = np.zeros(n_envs, dtype=bool)  # NEXT_STEP: envs whose episode ended last step

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        seeds = _seeds(seed, self.num_envs)
        scenarios = env_scenarios(options, self.num_envs)
        obs, infos = self.engine.reset_all(seeds, scenarios)
        self._to_reset[:] = False
        merged: dict[str, Any] = {}
        for i, info in enumerate(infos):
            merged = self._add_info(merged, info, i)
        return obs, merged

    def step(self, actions: Any) -> tuple[ObsArray, Any, Any, Any, dict[str, Any]]:
        engine = self.engine
        obs, reward, terminated, truncated, ended = engine.step(actions)  # ended envs do not step
        infos: dict[str, Any] = {}
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:
            for i in np.flatnonzero(self._to_reset).tolist() if self._to_reset.any() else ():
                infos = self._add_info(infos, _per_episode(engine._reset_or_recover(i)), i)
                obs[i], reward[i], terminated[i], truncated[i] = engine.obs[i], 0.0, False, False
            self._to_reset[:] = terminated | truncated
            for i, end in ended.items():
                infos = self._add_info(infos, _per_episode(end["final_info"]), i)
        else:
            for i, end in ended.items():
                infos = self._add_info(infos, end, i)
        infos["step"] = engine.samples.copy()
        infos["time_s"] = engine.plant.timing.start_time_s + engine.plant.k * engine.plant.timing.step_size_s
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.engine.close()


class BatchVecEnv(Sb3VecEnv):
    """stable-baselines3's ``VecEnv`` interface over :class:`BatchEnv` (same arguments).

    ``infos[i]`` is empty while env ``i``'s episode runs; when it ends it holds
    ``terminal_observation``, ``TimeLimit.truncated``, ``reason``, ``step``, ``time_s``,
    ``outputs`` (and ``plant_error`` after a failed step).
    """

    def __init__(self, experiment: Experiment | str | Path, n_envs: int, **kwargs: Any) -> None:
        super().__init__()
        self.engine = BatchEnv(experiment, n_envs, **kwargs)
        self.num_envs = n_envs
        self.observation_space = self.engine.task.observation_space
        self.action_space = self.engine.task.action_space
        self.render_mode = None
        self.metadata: dict[str, Any] = {"render_modes": []}
        self._seeds: list[int | None] = [None] * n_envs
        self._options: dict[str, Any] = {}
        self.reset_infos: list[dict[str, Any]] = [{} for _ in range(n_envs)]
        self._actions: Any = None

    def reset(self) -> ObsArray:
        scenarios = env_scenarios(self._options, self.num_envs)
        obs, self.reset_infos = self.engine.reset_all(self._seeds, scenarios)
        self._seeds, self._options = [None] * self.num_envs, {}
        return obs

    def step_async(self, actions: Any) -> None:
        self._actions = actions

    def step_wait(
        self,
    ) -> tuple[ObsArray, npt.NDArray[np.float32], npt.NDArray[np.bool_], list[dict[str, Any]]]:
        obs, reward, terminated, truncated, ended = self.engine.step(self._actions)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i, end in ended.items():
            info = infos[i] = end["final_info"]
            info["terminal_observation"] = end["final_obs"]
            info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            self.reset_infos[i] = end["reset_info"]
        return obs, reward.astype(np.float32), terminated | truncated, infos

    def seed(self, seed: int | None = None) -> list[int | None]:
        self._seeds = _seeds(self._new_seed(seed), self.num_envs)
        return list(self._seeds)

    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        if isinstance(options, list):
            self._options = {"scenario": [o.get("scenario") for o in options]}
        else:
            self._options = dict(options or {})

    def close(self) -> None:
        self.engine.close()


def _check_once_per_process(exp: Experiment, n_envs: int) -> None:
    """A batch steps its instances in this process: refuse several of a once-per-process FMU."""
    if n_envs < 2:
        return
    info = read_model_info(resolve_fmu(exp))  # what BatchPlant opens (cached)
    if info.once_per_process:
        raise ConfigError(
            f"{info.model_name} declares canBeInstantiatedOnlyOncePerProcess: the {n_envs} instances of a "
            f"batch env would share one process and its global state. Use n_envs=1 per process (e.g. one "
            f"per Ray env runner), or a PlantVecEnv of FmuEnv, which gives each instance its own process "
            f"[{info.path}]"
        )


def _per_episode(info: dict[str, Any]) -> dict[str, Any]:
    """An env's info less ``step`` and ``time_s`` (every env has them, as whole arrays)."""
    return {k: v for k, v in info.items() if k not in ("step", "time_s")}
