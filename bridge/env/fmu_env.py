"""``FmuEnv``: the one Gymnasium env, a ``Task`` over any plant.

The plant (``bridge.plant``) is where the model runs: in this process (the default,
``LocalFmuPlant``), in a node over Zenoh (``RemoteFmuEnv``), or any other plant. The env only
maps actions to inputs through the Task, steps the plant and turns outputs into observations,
rewards and episode ends. All randomness is drawn from ``self.np_random`` (seeded by
``reset(seed=...)``), so the same seed gives the same trajectory whatever the plant.

Errors: a failed model step, a plant that does not answer in time and a plant that is gone
raise ``StepError``, ``StepTimeout`` and ``PlantDied`` (all ``PlantError``) from ``step`` and
``reset``, with the same message shape for every plant; the episode is over, ``reset()`` starts
the next one. Vector envs can turn them into truncated episodes instead (``on_error``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError, PlantError, StepError
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.validate import check_experiment
from bridge.plant.base import Plant
from bridge.task import Task, load_callable
from bridge.task.core import NonFiniteOutputs

_log = logging.getLogger(__name__)
ObsType = npt.NDArray[np.float32]

__all__ = ["FmuEnv", "ObsType", "as_experiment", "make"]


class FmuEnv(gym.Env[ObsType, Any]):
    """A Gymnasium env: the experiment's Task over a plant.

    Args:
        experiment: an :class:`Experiment` or the path of an experiment YAML file.
        version: the env version (named observation/reward/termination set) to use.
        render_mode: ``"rgb_array"`` (the cart-pole drawn, else signal plots) or ``"ansi"``.
        plant: where the model runs; default: the experiment's FMU in this process. A plant
            given here is owned by the env from then on (``close()`` closes it).

    ``info`` holds ``time_s`` (simulation time), ``step`` (sample index), ``outputs`` (unscaled
    values of ``output_names``) and, at reset, ``scenario`` and the ``drawn`` uncertain values;
    at the end of an episode ``reason`` says why (``bounds:NAME``, ``fmu``, ``time``).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array", "ansi"], "render_fps": 50}

    def __init__(
        self,
        experiment: Experiment | str | Path,
        *,
        version: str | None = None,
        render_mode: str | None = None,
        plant: Plant | None = None,
    ) -> None:
        self.experiment = exp = as_experiment(experiment, version)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(
                f"render_mode {render_mode!r} is not supported; use one of {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode
        if plant is None:
            from bridge.env.plants import plant_for

            plant = plant_for(exp)
        self.plant = plant
        try:
            self.timing = t = plant.timing
            check_experiment(exp, plant.info)  # the task, once, against what the plant serves
            self.task = Task(exp, plant.info.variables, t)
            plant.bind(self.task.input_names, self.task.output_names)
            self._state_hook = load_callable(exp.hooks.state, "hooks.state") if exp.hooks.state else None
            if self._state_hook is not None and not plant.can_set_values:
                plant.set_values({})  # raises the plant's own "cannot" ConfigError
        except BaseException:
            plant.close()
            raise
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self.metadata = {**self.metadata, "render_fps": round(1.0 / t.sampling_time_s)}
        self.output_names = self.task.output_names
        self._sample = 0
        self._done = True
        self._trace: list[npt.NDArray[np.float64]] = []
        self._last_outputs = np.zeros(len(self.output_names))

    # -- Gymnasium API ----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsType, dict[str, Any]]:
        if seed is not None:  # gymnasium's reset only seeds np_random
            super().reset(seed=seed)
            self.task.sampler.restart()
        # A reset after an episode finds little of its code and data in the caches: what it touches
        # counts more than what it computes (benchmarks/bench_env.py), hence the locals.
        task, rng = self.task, self.np_random
        spec = task.new_episode(rng, options.get("scenario") if options else None)
        self._done = True
        plant = self.plant
        outputs = plant.reset(spec.values, task.initial_inputs())
        try:
            obs = task.first_observation(outputs.tolist(), rng)
        except NonFiniteOutputs as exc:
            raise plant.failure(StepError, "the model returned non-finite outputs", str(exc), step=0) from exc
        self._sample, self._done = 0, False
        self._last_outputs = outputs
        if self.render_mode == "rgb_array":
            self._record(outputs, reset=True)
        info = {
            "time_s": plant.time_s,
            "step": 0,
            "outputs": outputs,
            "scenario": spec.scenario,
            "drawn": dict(spec.drawn),
            **plant.reset_info(),
        }
        return obs, info

    def step(self, action: Any) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        # send() and receive() in one, inlined: this is the per-sample hot path
        if self._done:
            raise BridgeError("step() called on a finished or never-reset episode: call reset() first")
        inputs = self.task.action_to_inputs(action, self._sample, self.np_random)
        if self._state_hook is not None:
            self._apply_state_hook()
        try:
            outputs = self.plant.step(inputs)
        except PlantError:
            self._done = True
            raise
        return self._result(outputs)

    def send(self, action: Any) -> None:
        """First half of a step: map the action and hand the inputs to the plant.

        Vector envs send to every plant before receiving from any, so that plants in other
        processes or nodes step in parallel (``step`` is ``send`` then ``receive``)."""
        inputs = self._inputs_for(action)
        try:
            self.plant.send(inputs)
        except PlantError:
            self._done = True
            raise

    def receive(self) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Second half of a step: the plant's outputs turned into the task's result."""
        try:
            outputs = self.plant.receive()
        except PlantError:
            self._done = True
            raise
        return self._result(outputs)

    def _inputs_for(self, action: Any) -> list[float]:
        if self._done:
            raise BridgeError("step() called on a finished or never-reset episode: call reset() first")
        inputs = self.task.action_to_inputs(action, self._sample, self.np_random)
        if self._state_hook is not None:
            self._apply_state_hook()
        return inputs

    def _result(
        self, outputs: npt.NDArray[np.float64]
    ) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        plant = self.plant
        self._sample += 1
        try:
            obs, reward, terminated, truncated, reason = self.task.step_result(
                outputs.tolist(), self._sample, plant.terminated, self.np_random
            )
        except NonFiniteOutputs as exc:
            self._done = True
            raise plant.failure(
                StepError, "the model returned non-finite outputs", str(exc), step=self._sample
            ) from exc
        info: dict[str, Any] = {"time_s": plant.time_s, "step": self._sample, "outputs": outputs}
        if terminated or truncated:
            info["reason"] = reason
            self._done = True
        if self.render_mode is not None:
            self._record(outputs)
        return obs, reward, terminated, truncated, info

    def _apply_state_hook(self) -> None:
        assert self._state_hook is not None
        values = self._state_hook(self._sample, self.plant.time_s, self.task.signal_dict())
        if values:
            self.plant.set_values(values)

    def close(self) -> None:
        plant = getattr(self, "plant", None)
        if plant is not None:
            plant.close()

    # -- rendering --------------------------------------------------------------------------------
    def _record(self, outputs: npt.NDArray[np.float64], reset: bool = False) -> None:
        self._last_outputs = outputs
        if self.render_mode == "rgb_array":
            if reset:
                self._trace = []
            self._trace.append(np.concatenate([[self.plant.time_s], outputs]))

    def render(self) -> Any:
        from bridge.env import render

        names = list(self.output_names)
        if self.render_mode == "ansi":
            return render.ansi_line(self.plant.time_s, self._sample, names, self._last_outputs)
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
