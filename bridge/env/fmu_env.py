"""``FmuEnv``: a Gymnasium environment generated from an FMU and an experiment file.

The model runs in this process (fastest); ``bridge.net.remote.RemoteFmuEnv`` runs the same Task
against a node. All randomness is drawn from ``self.np_random`` (seeded by ``reset(seed=...)``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError
from bridge.experiment.config import Experiment, load_experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, timing
from bridge.fmu import Model, read_model_info
from bridge.task.core import Task, load_callable

_log = logging.getLogger(__name__)
ObsType = npt.NDArray[np.float32]


def as_experiment(experiment: Experiment | str | Path, version: str | None = None) -> Experiment:
    if isinstance(experiment, Experiment):
        return experiment.resolved(version) if version else experiment
    return load_experiment(experiment, version=version)


class FmuEnv(gym.Env[ObsType, Any]):
    """A Gymnasium env over one FMU instance.

    Args:
        experiment: an :class:`Experiment` or the path of an experiment YAML file.
        version: the env version (named observation/reward/termination set) to use.
        render_mode: ``"rgb_array"`` (the cart-pole drawn, else signal plots) or ``"ansi"``.

    ``info`` holds ``time_s`` (simulation time), ``step`` (sample index), ``outputs`` (unscaled
    values of ``output_names``) and, at reset, ``scenario`` and the ``drawn`` uncertain values;
    at the end of an episode ``reason`` says why (``bounds:NAME``, ``fmu``, or None for time).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array", "ansi"], "render_fps": 50}

    def __init__(
        self,
        experiment: Experiment | str | Path,
        *,
        version: str | None = None,
        render_mode: str | None = None,
    ) -> None:
        self.experiment = exp = as_experiment(experiment, version)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(
                f"render_mode {render_mode!r} is not supported; use one of {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode
        self.fmu_path = resolve_fmu(exp)
        info = check_experiment(exp, read_model_info(self.fmu_path))
        self.timing = t = timing(exp, info)
        self.task = Task(exp, info.variables, t)
        self.model = Model(
            self.fmu_path,
            step_size_s=t.step_size_s,
            start_time_s=t.start_time_s,
            interface=exp.model.interface,
            reset_policy=exp.model.reset_policy,
            tolerance=exp.model.tolerance,
        )
        try:
            self._inputs = self.model.signals(self.task.input_names, writable=True, role="input")
            self._outputs = self.model.signals(self.task.output_names, role="output")
        except BaseException:
            self.model.close()
            raise
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self.metadata = {**self.metadata, "render_fps": round(1.0 / t.sampling_time_s)}
        self.output_names = self.task.output_names
        self._n = t.steps_per_sample
        self._state_hook = load_callable(exp.hooks.state, "hooks.state") if exp.hooks.state else None
        self._sample = 0
        self._done = True
        self._trace: list[npt.NDArray[np.float64]] = []
        self._last_outputs = np.zeros(len(self.output_names))

    # -- Gymnasium API ----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsType, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.task.sampler.restart()
        scenario = (options or {}).get("scenario")
        spec = self.task.new_episode(self.np_random, scenario)
        self.model.reset(spec.values)
        self._inputs.write(self.task.initial_inputs())
        outputs = self._outputs.read()
        obs = self.task.first_observation(outputs.tolist(), self.np_random)
        self._sample, self._done = 0, False
        self._record(outputs, reset=True)
        info = {
            "time_s": self.model.time_s,
            "step": 0,
            "outputs": outputs,
            "scenario": spec.scenario,
            "drawn": dict(spec.drawn),
        }
        return obs, info

    def step(self, action: Any) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._done:
            raise BridgeError("step() called on a finished or never-reset episode: call reset() first")
        task = self.task
        inputs = task.action_to_inputs(action, self._sample, self.np_random)
        if self._state_hook is not None:
            self._apply_state_hook()
        self._inputs.write(inputs)
        fmu_terminated = self.model.advance(self._n)
        outputs = self._outputs.read()
        self._sample += 1
        obs, reward, terminated, truncated, reason = task.step_result(
            outputs.tolist(), self._sample, fmu_terminated, self.np_random
        )
        info: dict[str, Any] = {"time_s": self.model.time_s, "step": self._sample, "outputs": outputs}
        if terminated or truncated:
            info["reason"] = reason
            self._done = True
        if self.render_mode is not None:
            self._record(outputs)
        return obs, reward, terminated, truncated, info

    def _apply_state_hook(self) -> None:
        assert self._state_hook is not None
        values = self._state_hook(self._sample, self.model.time_s, self.task.signal_dict())
        if values:
            self.model.set(values)

    def close(self) -> None:
        model = getattr(self, "model", None)
        if model is not None:
            model.close()

    # -- rendering --------------------------------------------------------------------------------
    def _record(self, outputs: npt.NDArray[np.float64], reset: bool = False) -> None:
        self._last_outputs = outputs
        if self.render_mode == "rgb_array":
            if reset:
                self._trace = []
            self._trace.append(np.concatenate([[self.model.time_s], outputs]))

    def render(self) -> Any:
        from bridge.env import render

        names = list(self.output_names)
        if self.render_mode == "ansi":
            return render.ansi_line(self.model.time_s, self._sample, names, self._last_outputs)
        if self.render_mode != "rgb_array":
            return None
        if "x" in names and "theta" in names:
            limit = self.experiment.termination.bounds.get("x", (None, 2.4))[1] or 2.4
            return render.draw_cartpole(
                float(self._last_outputs[names.index("x")]),
                float(self._last_outputs[names.index("theta")]),
                x_limit=float(limit),
            )
        trace = np.array(self._trace)
        return render.plot_signals(
            trace[:, 0], {n: trace[:, i + 1] for i, n in enumerate(names)}, title=self.experiment.name
        )


def make(experiment: Experiment | str | Path, **kwargs: Any) -> FmuEnv:
    """An :class:`FmuEnv` for ``experiment`` (a path, an :class:`Experiment`, or an example name)."""
    if isinstance(experiment, str) and not experiment.endswith((".yaml", ".yml")):
        from bridge.experiment.examples import example_experiment

        experiment = example_experiment(experiment)
    return FmuEnv(experiment, **kwargs)


def _register() -> None:
    from bridge.experiment.examples import register_envs

    register_envs()


_register()
