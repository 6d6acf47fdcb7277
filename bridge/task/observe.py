"""Observation processing: selection, sensor noise, scaling, tracking errors, last action, history.

Scaling maps a signal's range to about [-1, 1]: ``(x - centre) / half_range``. The range comes
from ``observations.scale`` when given, else (``auto``) from the FMU's min/max, else from the
termination bounds, else from the nominal value; references and errors share the scale of the
output they track.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.experiment.config import ObservationSection
from bridge.fmu.vocab import Variable
from bridge.task.scenario import noise_table

if TYPE_CHECKING:
    from bridge.task.core import Task

FloatArray = npt.NDArray[np.float64]
_NO_NOISE: list[float] = []


class ObservationBuilder:
    """Builds the observation vector from the task's signal vector (one instance per task)."""

    def __init__(self, task: Task, section: ObservationSection, variables: Mapping[str, Variable]) -> None:
        self._section = section
        self._variables = variables
        self._bounds = task.experiment.termination.bounds
        index = {name: i for i, name in enumerate(task.signal_names)}
        direct = [*section.outputs, *section.references]
        self._direct_list = [index[n] for n in direct]
        self._errors = [(index[r], index[o]) for r, o in section.errors.items()]
        self._n_action = len(task.action_inputs) if section.include_action else 0
        self.names = (
            direct
            + [f"{r}-{o}" for r, o in section.errors.items()]
            + [f"action:{a}" for a in task.action_inputs[: self._n_action]]
        )
        self.dim = len(self.names)
        centre, half = self._scales(section, task)
        self._centre_list, self._inv_list = centre.tolist(), (1.0 / half).tolist()
        noise = task.experiment.noise.observations
        self._noise = [(section.outputs.index(n), d) for n, d in noise.items()]
        self._noise_table: list[list[float]] = []
        self._sample = 0
        self._compiled = self._compile()
        self._history: deque[list[float]] = deque(maxlen=section.history)
        bound = section.clip if section.clip is not None else np.inf
        self.space = gym.spaces.Box(-bound, bound, shape=(section.history * self.dim,), dtype=np.float32)

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
        bound_low, bound_high = self._bounds.get(name, (None, None))
        if (
            bound_low is not None
            and bound_high is not None
            and _finite(bound_low, bound_high)
            and (bound_high > bound_low)
        ):
            return (bound_high + bound_low) / 2, (bound_high - bound_low) / 2
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

    def _compile(self) -> Callable[[list[float], list[float], list[float]], list[float]]:
        """``lambda s, u, nz: [...]``: one expression per observation element, constants inlined.

        The source is generated from indices and floats computed here (never from user text); a
        single list display avoids the per-element cost of zip, comprehensions and numpy calls,
        which dominate for the handful of values an observation has.
        """
        noise_slot = {i: k for k, (i, _) in enumerate(self._noise)}
        raw = [
            f"s[{i}]" + (f" + nz[{noise_slot[p]}]" if p in noise_slot else "")
            for p, i in enumerate(self._direct_list)
        ]
        raw += [f"s[{r}] - s[{o}]" for r, o in self._errors]
        raw += [f"u[{j}]" for j in range(self._n_action)]
        terms = [f"({x} - {c!r}) * {k!r}" for x, c, k in zip(raw, self._centre_list, self._inv_list)]
        clip = self._section.clip
        if clip is not None:
            terms = [f"min(max({t}, {-clip!r}), {clip!r})" for t in terms]
        source = f"lambda s, u, nz: [{', '.join(terms)}]"
        self.source = source  # also evaluated over whole batches by bridge.task.batch
        return eval(source, {"__builtins__": {}, "min": min, "max": max})  # type: ignore[no-any-return]

    @property
    def history_length(self) -> int:
        """Observations stacked per step (``observations.history``)."""
        return self._section.history

    @property
    def has_noise(self) -> bool:
        """Whether sensor noise is added to some observed outputs."""
        return bool(self._noise)

    @property
    def noise_table(self) -> list[list[float]]:
        """This episode's sensor noise, one row per sample, one column per noisy output."""
        return self._noise_table

    # -- per sample ---------------------------------------------------------------------------------
    def new_episode(self, rng: np.random.Generator, rows: int) -> None:
        """Draw the sensor noise of a whole episode at once (rows = samples + 1)."""
        self._noise_table = noise_table(self._noise, rng, rows)
        self._sample = 0

    def _single(self, signals: list[float], inputs: list[float], rng: np.random.Generator) -> list[float]:
        if self._noise:
            row = self._noise_table[min(self._sample, len(self._noise_table) - 1)]
            self._sample += 1
            return self._compiled(signals, inputs, row)
        return self._compiled(signals, inputs, _NO_NOISE)

    def reset(
        self, signals: list[float], inputs: list[float], rng: np.random.Generator
    ) -> npt.NDArray[np.float32]:
        first = self._single(signals, inputs, rng)
        if self._section.history == 1:  # as observe() does: no history to keep
            return np.array(first, dtype=np.float32)
        self._history = deque([first] * self._section.history, maxlen=self._section.history)
        return self._stack()

    def observe(
        self, signals: list[float], inputs: list[float], rng: np.random.Generator
    ) -> npt.NDArray[np.float32]:
        if self._section.history == 1:
            return np.array(self._single(signals, inputs, rng), dtype=np.float32)
        self._history.append(self._single(signals, inputs, rng))
        return self._stack()

    def _stack(self) -> npt.NDArray[np.float32]:
        return np.array([v for row in self._history for v in row], dtype=np.float32)


def _finite(*values: float | None) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


def _tracked_by_reward(task: Task) -> dict[str, str]:
    return {t.tracking.reference: t.tracking.output for t in task.experiment.reward.terms if t.tracking}


def _action_ranges(task: Task) -> list[tuple[float, float]]:
    from bridge.experiment.validate import action_bounds

    ranges = []
    for name in task.action_inputs:
        low, high = action_bounds(task.experiment, task.variables[name])
        if _finite(low, high) and high > low:  # type: ignore[operator]
            ranges.append(((high + low) / 2, (high - low) / 2))  # type: ignore[operator]
        else:
            ranges.append((0.0, 1.0))
    return ranges
