"""Several agents in one system: a PettingZoo ``ParallelEnv`` over a :class:`SystemPlant`.

Each agent of ``system.agents`` drives its own inputs, observes its own outputs and has its own
reward; all act at once every sample (``model.sampling_time``), the system steps once, and each
gets its observation and reward. An episode lasts ``model.episode_duration`` (truncation for
every agent); a component that asks to stop ends it for every agent (termination). Actions are in
[-1, 1], scaled to the agent's ``low``/``high`` (default: the inputs' min/max in the FMU);
observations are the outputs as they are (float32). Reset with the same seed replays the same
episode: the system holds no randomness of its own.

``pettingzoo`` is an optional dependency (``pip install fmu-bridge[multiagent]``).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from pydantic import ValidationError

from bridge.errors import ConfigError, DependencyMissing
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.reward import RewardSection
from bridge.experiment.strict import format_validation_error
from bridge.experiment.system import AgentSection
from bridge.experiment.validate import check_experiment
from bridge.plant.base import FloatArray, Plant
from bridge.task.rewards import Reward, build_reward, reward_signal_names

try:
    from pettingzoo import ParallelEnv
except ImportError as exc:  # pragma: no cover - the extra is not installed
    raise DependencyMissing(
        "pettingzoo",
        "several agents in one system (bridge.env.multi_agent)",
        "pip install 'fmu-bridge[multiagent]'",
    ) from exc


class _Agent:
    """One agent's slice of the system: where its actions go and what it reads."""

    def __init__(self, name: str, spec: AgentSection, plant: Plant, exp: Experiment) -> None:
        self.name, self.spec = name, spec
        where = f" [{exp.source}]" if exp.source else ""
        self.low, self.high = _bounds(name, spec, plant, where)
        try:
            section = RewardSection.model_validate(spec.reward)
        except ValidationError as exc:
            raise ConfigError(
                format_validation_error(exc, exp.source, f"system.agents.{name}.reward.")
            ) from None
        read = reward_signal_names(section, set(plant.info.variables))
        self.signals = list(dict.fromkeys([*spec.observations, *read]))
        self.reward: Reward = build_reward(section, self.signals, spec.inputs)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (len(spec.inputs),), np.float32)
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (len(spec.observations),), np.float32)

    def inputs(self, action: Any) -> FloatArray:
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        result: FloatArray = self.low + (a + 1.0) * 0.5 * (self.high - self.low)
        return result


def _bounds(name: str, spec: AgentSection, plant: Plant, where: str) -> tuple[FloatArray, FloatArray]:
    low, high = [], []
    for inp in spec.inputs:
        var = plant.info.variables.get(inp)
        if var is None:
            raise ConfigError(f"system.agents.{name}.inputs: {inp!r} is not a variable of the system{where}")
        lo = spec.low.get(inp, var.min)
        hi = spec.high.get(inp, var.max)
        if lo is None or hi is None or not np.isfinite([lo, hi]).all() or not lo < hi:
            raise ConfigError(
                f"system.agents.{name}: {inp!r} needs finite bounds low < high (got {lo}, {hi}); "
                f"set system.agents.{name}.low and .high{where}"
            )
        low.append(lo)
        high.append(hi)
    return np.array(low, dtype=np.float64), np.array(high, dtype=np.float64)


class SystemParallelEnv(ParallelEnv):  # type: ignore[misc]
    """The system of ``experiment`` with the agents of its ``system.agents`` (PettingZoo Parallel API).

    Args:
        experiment: an experiment (or its file) with a ``system:`` section that names agents.
        plant: the system's plant (default: built as the single-agent env builds it).
    """

    metadata = {"name": "fmu_bridge_system_v0", "render_modes": []}

    def __init__(self, experiment: Experiment | str | Path, *, plant: Plant | None = None) -> None:
        self.experiment = exp = as_experiment(experiment)
        where = f" [{exp.source}]" if exp.source else ""
        section = exp.system
        if section is None or len(section.agents) == 0:
            raise ConfigError(f"system.agents: name at least one agent (inputs, observations, reward){where}")
        if plant is None:
            from bridge.env.plants import plant_for

            plant = plant_for(exp)
        self.plant = plant
        try:
            check_experiment(exp, plant.info)  # the task, once, against what the plant serves
            self._agents = {n: _Agent(n, s, plant, exp) for n, s in section.agents.items()}
            self._bind(where)
        except BaseException:
            plant.close()
            raise
        self.possible_agents = list(self._agents)
        self.agents: list[str] = []
        self.applied_inputs: dict[str, FloatArray] = {}  # each agent's FMU input values of the last step
        self._samples = round(exp.model.episode_duration / plant.timing.sampling_time_s)
        self._sample = 0

    def _bind(self, where: str) -> None:
        inputs = [i for a in self._agents.values() for i in a.spec.inputs]
        twice = sorted({i for i in inputs if inputs.count(i) > 1})
        if twice:
            raise ConfigError(
                f"system.agents: {twice} driven by more than one agent; an input has one driver{where}"
            )
        outputs = list(dict.fromkeys(s for a in self._agents.values() for s in a.signals))
        self.plant.bind(inputs, outputs)
        self._slots = {n: [outputs.index(s) for s in a.signals] for n, a in self._agents.items()}
        self._obs = {n: len(a.spec.observations) for n, a in self._agents.items()}
        self._start = np.array([float(self.plant.info.variables[i].start or 0.0) for i in inputs])

    @functools.cache  # noqa: B019 (PettingZoo's pattern: one space per agent)
    def observation_space(self, agent: str) -> gymnasium.spaces.Space[Any]:
        return self._agents[agent].observation_space

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> gymnasium.spaces.Space[Any]:
        return self._agents[agent].action_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        exp = self.experiment
        self.agents = list(self.possible_agents)
        self._sample = 0
        self._previous = {n: a.inputs(np.zeros(len(a.spec.inputs))) for n, a in self._agents.items()}
        outputs = self.plant.reset({**exp.model.parameters, **exp.model.start_values}, self._start.tolist())
        return self._observe(outputs), {n: {"time_s": self.plant.time_s} for n in self.agents}

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, Any]]:
        missing = [n for n in self.agents if n not in actions]
        if missing:
            raise ConfigError(f"step: no action for agents {missing}; every live agent acts each sample")
        inputs = {n: a.inputs(actions[n]) for n, a in self._agents.items()}
        outputs = self.plant.step(np.concatenate(list(inputs.values())).tolist())
        self._sample += 1
        terminated = bool(self.plant.terminated)
        truncated = self._sample >= self._samples and not terminated
        rewards = {n: self._reward(n, outputs, inputs[n], terminated) for n in self._agents}
        self._previous = self.applied_inputs = inputs
        observations = self._observe(outputs)
        agents = list(self.agents)
        infos = {n: {"time_s": self.plant.time_s} for n in agents}
        if terminated or truncated:
            self.agents = []
        return (
            {n: observations[n] for n in agents},
            {n: rewards[n] for n in agents},
            dict.fromkeys(agents, terminated),
            dict.fromkeys(agents, truncated),
            infos,
        )

    def _reward(self, name: str, outputs: FloatArray, inputs: FloatArray, terminated: bool) -> float:
        signals = [float(outputs[i]) for i in self._slots[name]]
        previous = self._previous[name].tolist()
        return float(self._agents[name].reward(signals, inputs.tolist(), previous, terminated))

    def _observe(self, outputs: FloatArray) -> dict[str, Any]:
        return {
            n: np.asarray([outputs[i] for i in self._slots[n][: self._obs[n]]], dtype=np.float32)
            for n in self._agents
        }

    def close(self) -> None:
        self.plant.close()
