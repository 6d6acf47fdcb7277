"""Observation processing: selection, sensor noise, scaling, tracking errors, last action, history.

Scaling maps a signal's range to about [-1, 1]: ``(x - centre) / half_range``. The range comes
from ``observations.scale`` when given, else (``auto``) from the FMU's min/max, else from the
termination bounds, else from the nominal value; references and errors share the scale of the
output they track.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.config import ObservationSection
from bridge.fmu import Variable
from bridge.scenario import draw

if TYPE_CHECKING:
    from bridge.task import Task

FloatArray = npt.NDArray[np.float64]


class ObservationBuilder:
    """Builds the observation vector from the task's signal vector (one instance per task)."""

    def __init__(self, task: Task, section: ObservationSection, variables: Mapping[str, Variable]) -> None:
        self._section = section
        self._variables = variables
        self._bounds = task.experiment.termination.bounds
        index = {name: i for i, name in enumerate(task.signal_names)}
        direct = [*section.outputs, *section.references]
        self._direct = np.array([index[n] for n in direct], dtype=np.intp)
        self._err_ref = np.array([index[r] for r in section.errors], dtype=np.intp)
        self._err_out = np.array([index[o] for o in section.errors.values()], dtype=np.intp)
        self._n_action = len(task.action_inputs) if section.include_action else 0
        self.names = (
            direct + [f"{r}-{o}" for r, o in section.errors.items()]
            + [f"action:{a}" for a in task.action_inputs[: self._n_action]]
        )
        centre, half = self._scales(section, task)
        self._centre, self._inv_half = centre, 1.0 / half
        noise = task.experiment.noise.observations
        self._noise = [(section.outputs.index(n), d) for n, d in noise.items()]
        self.dim = len(self.names)
        self._history = np.zeros((section.history, self.dim), dtype=np.float32)
        bound = section.clip if section.clip is not None else np.inf
        self.space = gym.spaces.Box(-bound, bound, shape=(section.history * self.dim,), dtype=np.float32)
        self._raw = np.zeros(self.dim)

    # -- scaling ------------------------------------------------------------------------------------
    def _range(self, name: str) -> tuple[float, float]:
        section = self._section
        if isinstance(section.scale, dict) and name in section.scale:
            low, high = section.scale[name]
            return (low + high) / 2, (high - low) / 2
        if section.scale == "none":
            return 0.0, 1.0
        var = self._variables.get(name)
        if var is not None and _finite(var.min, var.max) and var.max > var.min:  # type: ignore[operator]
            return (var.max + var.min) / 2, (var.max - var.min) / 2  # type: ignore[operator]
        low, high = self._bounds.get(name, (None, None))
        if _finite(low, high) and high > low:  # type: ignore[operator]
            return (high + low) / 2, (high - low) / 2  # type: ignore[operator]
        if var is not None and var.nominal and math.isfinite(var.nominal):
            return 0.0, abs(var.nominal)
        return 0.0, 1.0

    def _scales(self, section: ObservationSection, task: Task) -> tuple[FloatArray, FloatArray]:
        tracked = {ref: out for ref, out in section.errors.items()}
        tracked.update(_tracked_by_reward(task))
        ranges = [self._range(n) for n in section.outputs]
        for ref in section.references:
            explicit = isinstance(section.scale, dict) and ref in section.scale
            ranges.append(self._range(ref if explicit or ref not in tracked else tracked[ref]))
        ranges += [(0.0, self._range(out)[1]) for out in section.errors.values()]
        if self._n_action:
            ranges += [(c, h) for c, h in _action_ranges(task)]
        centre = np.array([r[0] for r in ranges], dtype=np.float64)
        half = np.array([r[1] for r in ranges], dtype=np.float64)
        return centre, np.where(half > 0, half, 1.0)

    # -- per sample ---------------------------------------------------------------------------------
    def _single(self, signals: FloatArray, inputs: FloatArray, rng: np.random.Generator) -> FloatArray:
        raw = self._raw
        nd = len(self._direct)
        raw[:nd] = signals[self._direct]
        for i, dist in self._noise:
            raw[i] += draw(dist, rng)
        ne = len(self._err_ref)
        if ne:
            raw[nd : nd + ne] = signals[self._err_ref] - signals[self._err_out]
        if self._n_action:
            raw[nd + ne :] = inputs[: self._n_action]
        scaled = (raw - self._centre) * self._inv_half
        if self._section.clip is not None:
            np.clip(scaled, -self._section.clip, self._section.clip, out=scaled)
        return scaled

    def reset(self, signals: FloatArray, inputs: FloatArray, rng: np.random.Generator) -> npt.NDArray[np.float32]:
        self._history[:] = self._single(signals, inputs, rng)
        return self._history.reshape(-1).copy()

    def observe(self, signals: FloatArray, inputs: FloatArray, rng: np.random.Generator) -> npt.NDArray[np.float32]:
        history = self._history
        if len(history) > 1:
            history[:-1] = history[1:]
        history[-1] = self._single(signals, inputs, rng)
        return history.reshape(-1).copy()


def _finite(*values: float | None) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


def _tracked_by_reward(task: Task) -> dict[str, str]:
    return {t.tracking.reference: t.tracking.output for t in task.experiment.reward.terms if t.tracking}


def _action_ranges(task: Task) -> list[tuple[float, float]]:
    from bridge.config_check import action_bounds

    ranges = []
    for name in task.action_inputs:
        low, high = action_bounds(task.experiment, task._variables[name])
        if _finite(low, high) and high > low:  # type: ignore[operator]
            ranges.append(((high + low) / 2, (high - low) / 2))  # type: ignore[operator]
        else:
            ranges.append((0.0, 1.0))
    return ranges
