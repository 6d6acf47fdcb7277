"""Scenarios, uncertainty and schedules: what each episode gets, drawn from the env's generator.

All randomness comes from the ``numpy.random.Generator`` passed in (the env's ``np_random``),
so the same seed reproduces an episode exactly: scenario choice, sampled parameters, set-points
and noise included.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError
from bridge.experiment.config import Distribution, Experiment, Profile, Randomization, Scenario

FloatArray = npt.NDArray[np.float64]
_MAX_REJECTIONS = 10_000


def draw(dist: Distribution, rng: np.random.Generator) -> float:
    """One value from ``dist``."""
    if dist.uniform is not None:
        return float(rng.uniform(*dist.uniform))
    if dist.normal is not None:
        return float(rng.normal(*dist.normal))
    if dist.truncnormal is not None:
        mean, std, low, high = dist.truncnormal
        for _ in range(_MAX_REJECTIONS):
            value = float(rng.normal(mean, std))
            if low <= value <= high:
                return value
        raise ConfigError(
            f"truncnormal {list(dist.truncnormal)}: [low, high] lies too far in the tail to sample; "
            "move the mean inside the bounds or widen them"
        )
    if dist.lognormal is not None:
        median, sigma = dist.lognormal
        return float(median * math.exp(rng.normal(0.0, sigma)))
    assert dist.choice is not None  # the validator guarantees exactly one kind
    weights = None
    if dist.weights is not None:
        total = sum(dist.weights)
        weights = [w / total for w in dist.weights]
    return float(dist.choice[int(rng.choice(len(dist.choice), p=weights))])


def draw_many(dist: Distribution, rng: np.random.Generator, size: int) -> FloatArray:
    """``size`` independent values from ``dist`` in one vectorised draw (noise for a whole episode)."""
    if dist.uniform is not None:
        return rng.uniform(*dist.uniform, size=size)
    if dist.normal is not None:
        return rng.normal(*dist.normal, size=size)
    if dist.lognormal is not None:
        median, sigma = dist.lognormal
        return np.asarray(median * np.exp(rng.normal(0.0, sigma, size=size)))
    if dist.choice is not None:
        weights = None if dist.weights is None else np.asarray(dist.weights) / sum(dist.weights)
        return np.asarray(dist.choice, dtype=np.float64)[rng.choice(len(dist.choice), size=size, p=weights)]
    return np.array([draw(dist, rng) for _ in range(size)])


def evaluate(profile: Profile, times: FloatArray, base_dir: Path) -> FloatArray:
    """The profile's values at ``times`` (seconds)."""
    values = _evaluate_one(profile, times, base_dir)
    for extra in profile.add:
        values = values + evaluate(extra, times, base_dir)
    return values


def _evaluate_one(profile: Profile, times: FloatArray, base_dir: Path) -> FloatArray:
    if profile.constant is not None:
        return np.full_like(times, profile.constant)
    if profile.step is not None:
        s = profile.step
        return np.where(times >= s.time, s.after, s.before).astype(np.float64)
    if profile.ramp is not None:
        r = profile.ramp
        fraction = np.clip((times - r.start_time) / (r.end_time - r.start_time), 0.0, 1.0)
        return np.asarray(r.start + fraction * (r.end - r.start), dtype=np.float64)
    if profile.sine is not None:
        w = profile.sine
        return np.asarray(w.offset + w.amplitude * np.sin(2 * np.pi * w.frequency_hz * times + w.phase_rad))
    if profile.table is not None:
        t = profile.table
        return _interpolate(np.asarray(t.time), np.asarray(t.value), times, t.interpolation)
    assert profile.csv is not None
    table_t, table_v = _read_csv(base_dir / profile.csv.file, profile.csv.time_column, profile.csv.column)
    return _interpolate(table_t, table_v, times, profile.csv.interpolation)


def _interpolate(t: FloatArray, v: FloatArray, times: FloatArray, how: str) -> FloatArray:
    if how == "linear":
        return np.interp(times, t, v).astype(np.float64)
    index = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
    return v[index].astype(np.float64)


def _read_csv(path: Path, time_column: str, column: str) -> tuple[FloatArray, FloatArray]:
    try:
        with path.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
    except OSError as exc:
        raise ConfigError(f"profile csv: cannot read {path}: {exc.strerror}") from exc
    if not rows or time_column not in rows[0] or column not in rows[0]:
        found = list(rows[0]) if rows else []
        raise ConfigError(f"profile csv: {path} needs columns {time_column!r} and {column!r}; it has {found}")
    try:
        t = np.array([float(r[time_column]) for r in rows])
        v = np.array([float(r[column]) for r in rows])
    except ValueError as exc:
        raise ConfigError(f"profile csv: {path}: a value is not a number ({exc})") from exc
    if np.any(np.diff(t) < 0):
        raise ConfigError(f"profile csv: {path}: column {time_column!r} must be non-decreasing")
    return t, v


def noise_table(
    entries: Sequence[tuple[int, Distribution]], rng: np.random.Generator, rows: int
) -> list[list[float]]:
    """``rows`` draws of each entry's distribution (a column per entry): an episode's noise at once."""
    if not entries:
        return []
    return np.column_stack([draw_many(dist, rng, rows) for _, dist in entries]).tolist()  # type: ignore[no-any-return]


@dataclass
class EpisodeSpec:
    """What one episode gets; hooks may return a modified copy (``dataclasses.replace``)."""

    scenario: str
    values: dict[str, Any]
    references: dict[str, FloatArray] = field(default_factory=dict)
    inputs: dict[str, FloatArray] = field(default_factory=dict)
    drawn: dict[str, float] = field(default_factory=dict)
    n_samples: int = 0

    def with_values(self, **values: Any) -> EpisodeSpec:
        return replace(self, values={**self.values, **values})


@dataclass(frozen=True)
class _Plan:
    """One scenario's fixed values, the draws in their order, and its sample times."""

    values: dict[str, Any]
    draws: tuple[tuple[str, Distribution], ...]
    profiles: bool  # references or input profiles, evaluated per episode on ``times``
    times: FloatArray
    n_samples: int


class ScenarioSampler:
    """Chooses a scenario per episode and draws its uncertain values."""

    def __init__(self, experiment: Experiment, sample_times: Callable[[float | None], FloatArray]) -> None:
        self._exp = experiment
        self._times = sample_times
        self._scenarios: dict[str, Scenario] = dict(experiment.scenarios) or {"nominal": Scenario()}
        schedule = experiment.schedule
        self.training = list(schedule.training) or list(self._scenarios)
        self.evaluation = list(schedule.evaluation)
        self._mode = schedule.mode
        self._weights = np.array([schedule.weights.get(n, 1.0) for n in self.training], dtype=np.float64)
        if self._mode == "weighted" and self._weights.sum() <= 0:
            raise ConfigError("schedule.weights: at least one training scenario needs a positive weight")
        self._next = 0
        self._plans: dict[str, _Plan] = {}

    @property
    def names(self) -> list[str]:
        return list(self._scenarios)

    def restart(self) -> None:
        """Start the round-robin order again (on reset with a seed, so a seed fixes the sequence)."""
        self._next = 0

    def choose(self, rng: np.random.Generator, pool: Sequence[str] | None = None) -> str:
        names = list(pool) if pool else self.training
        if self._mode == "fixed" or len(names) == 1:
            return names[0]
        if self._mode == "round_robin":
            name = names[self._next % len(names)]
            self._next += 1
            return name
        if self._mode == "weighted" and pool is None:
            return names[int(rng.choice(len(names), p=self._weights / self._weights.sum()))]
        return names[int(rng.integers(len(names)))]

    def repeats(self) -> bool:
        """Whether every training episode is the same one, drawn without the generator: one
        scenario chosen without a draw, no value drawn, no reference or input profile."""
        names = self.training
        if not (self._mode == "fixed" or len(names) == 1):
            return False
        plan = self._plans.get(names[0]) or self._plan(names[0])
        return not plan.draws and not plan.profiles

    def episode(self, rng: np.random.Generator, scenario: str | None = None) -> EpisodeSpec:
        """Everything an episode needs; ``scenario`` forces one by name."""
        name = scenario or self.choose(rng)
        plan = self._plans.get(name) or self._plan(name)
        values = dict(plan.values)
        drawn: dict[str, float] = {}
        for var, dist in plan.draws:
            drawn[var] = values[var] = draw(dist, rng)
        if not plan.profiles:  # values only (the common case): nothing depends on the sample times
            return EpisodeSpec(name, values, {}, {}, drawn, n_samples=plan.n_samples)
        sc, times, base = self._scenarios[name], plan.times, self._exp.base_dir
        references = {n: evaluate(p, times, base) for n, p in sc.references.items()}
        for rand in (self._exp.randomization, sc.randomization):
            references.update(_drawn_references(rand, times, rng, drawn))
        inputs = {n: evaluate(p, times, base) for n, p in sc.inputs.items()}
        return EpisodeSpec(name, values, references, inputs, drawn, n_samples=plan.n_samples)

    def _plan(self, name: str) -> _Plan:
        """What every episode of scenario ``name`` shares, worked out once (a reset stays cheap)."""
        if name not in self._scenarios:
            raise ConfigError(f"scenario {name!r} is not defined; defined: {sorted(self._scenarios)}")
        sc, model = self._scenarios[name], self._exp.model
        rands = (self._exp.randomization, sc.randomization)
        times = self._times(sc.episode_duration)
        times.flags.writeable = False
        self._plans[name] = plan = _Plan(
            values={**model.parameters, **model.start_values, **sc.parameters, **sc.start_values},
            draws=tuple(
                item for r in rands for section in (r.parameters, r.start_values) for item in section.items()
            ),
            profiles=bool(sc.references or sc.inputs or any(r.references for r in rands)),
            times=times,
            n_samples=len(times) - 1,
        )
        return plan


def _drawn_references(
    rand: Randomization, times: FloatArray, rng: np.random.Generator, drawn: dict[str, float]
) -> dict[str, FloatArray]:
    out = {}
    for name, dist in rand.references.items():
        drawn[name] = value = draw(dist, rng)
        out[name] = np.full_like(times, value)
    return out


def describe(spec: EpisodeSpec) -> Mapping[str, Any]:
    """A short, printable summary of an episode (for ``fmu-bridge scenarios``)."""
    return {
        "scenario": spec.scenario,
        "values": spec.values,
        "drawn": spec.drawn,
        "references": {n: (float(v[0]), float(v[-1])) for n, v in spec.references.items()},
        "inputs": {n: (float(v.min()), float(v.max())) for n, v in spec.inputs.items()},
    }
