"""``Task``: everything an experiment adds on top of a model, independent of where the model runs.

Action mapping, observation processing (selection, scaling, history, noise), reward,
termination and per-episode scenarios run identically in-process (``FmuEnv``), against a
remote node (``RemoteFmuEnv``) and inside a deployed agent node. The model side only sees
``input_names`` written and ``output_names`` read once per sample.

Time: sample ``j`` spans FMU steps ``j*n .. (j+1)*n``; the action of sample ``j`` (and the
scenario's input profiles at ``t_j``) are held over it; the observation and reward of that
step use outputs and references at ``t_{j+1}``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError
from bridge.experiment.config import Experiment, known_references, scenario_inputs
from bridge.experiment.safe import check_own_module
from bridge.experiment.validate import Timing, action_bounds, with_elements
from bridge.fmu.vocab import Variable
from bridge.task.observe import ObservationBuilder
from bridge.task.rewards import build_reward, reward_signal_names
from bridge.task.scenario import EpisodeSpec, ScenarioSampler, noise_table

FloatArray = npt.NDArray[np.float64]


class NonFiniteOutputs(BridgeError):
    """The model returned NaN or infinite outputs (the env reports it as the plant's StepError)."""


def load_callable(path: str, key: str) -> Callable[..., Any]:
    """Import ``module:function`` named at config ``key``."""
    module_name, _, attr = path.partition(":")
    try:
        check_own_module(module_name)  # before the import: importing runs the module's code
    except ValueError as exc:
        raise ConfigError(f"{key}: {exc}") from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"{key}: cannot import module {module_name!r} ({exc}); is it on PYTHONPATH?"
        ) from exc
    fn = getattr(module, attr, None)
    if not callable(fn):
        raise ConfigError(f"{key}: {module_name} has no callable {attr!r}")
    return fn  # type: ignore[no-any-return]


@dataclass(frozen=True)
class ActionMapping:
    """How a :class:`Task` turns actions into FMU inputs (the batch task applies it over N envs).

    ``kind`` is the experiment's ``actions.type``; continuous actions in [-1, 1] map to
    ``centre + half * a``; a discrete action picks a row of ``table``; a multi-discrete one picks
    one of ``levels[j]`` per input; actuator noise is added to the inputs ``noise_columns``.
    """

    kind: str
    centre: list[float] = field(default_factory=list)
    half: list[float] = field(default_factory=list)
    table: list[list[float]] = field(default_factory=list)
    levels: list[FloatArray] = field(default_factory=list)
    noise_columns: list[int] = field(default_factory=list)


class ExactAction(np.ndarray[Any, np.dtype[np.float64]]):
    """A continuous action that also carries the physical input values it stands for.

    Every env and wrapper sees an ordinary float64 action in [-1, 1]; :meth:`Task.action_to_inputs`
    applies ``physical`` instead of mapping the action back, so a value the user gave in physical
    units (``--policy constant:0.9``) reaches the FMU exactly (the mapping ``centre + half * a``
    cannot give every float, its bounds among them). Fixed policies use it; agents do not.
    """

    physical: list[float] | None

    def __new__(cls, action: Any, physical: list[float]) -> ExactAction:
        obj = np.asarray(action, dtype=np.float64).view(cls)
        obj.physical = [float(v) for v in physical]
        return obj

    def __array_finalize__(self, obj: Any) -> None:
        self.physical = getattr(obj, "physical", None)


@dataclass(frozen=True)
class EpisodeTables:
    """The current episode's per-sample tables, one row per sample ``0..n``."""

    references: FloatArray  # reference_names columns
    profile_inputs: FloatArray  # the scenario-driven inputs after the action inputs
    action_noise: FloatArray  # one column per noisy action input (ActionMapping.noise_columns)
    observation_noise: FloatArray  # one column per noisy observed output


class SignalNames(NamedTuple):
    """The signals a task exchanges with its model, in the order the task lays them out."""

    inputs: tuple[str, ...]  # the action inputs, then the scenario-driven inputs
    outputs: tuple[str, ...]  # the model variables the task reads (not inputs, not references)
    references: tuple[str, ...]  # the scenario references the task reads


def task_signal_names(exp: Experiment, variables: Collection[str]) -> SignalNames:
    """The inputs, outputs and references of :class:`Task` for ``exp`` over a model with
    ``variables`` (names, array elements included). Names the experiment reads are taken as
    written; only ``reward.expression`` is resolved against ``variables`` and the references
    (an unknown name there is a ConfigError)."""
    refs_known = known_references(exp)
    obs = exp.observations
    wanted = [*obs.outputs, *obs.errors.values(), *obs.references, *obs.errors]
    wanted += reward_signal_names(exp.reward, set(variables) | refs_known)
    wanted += list(exp.termination.bounds)
    inputs = tuple(exp.actions.inputs) + tuple(scenario_inputs(exp))
    outputs: list[str] = []
    references: list[str] = []
    for name in wanted:
        if name in refs_known and name not in variables:
            if name not in references:
                references.append(name)
        elif name not in inputs and name not in outputs:
            outputs.append(name)
    return SignalNames(inputs, tuple(outputs), tuple(references))


class Task:
    """The task side of an experiment (one instance per env; holds per-episode state)."""

    def __init__(self, experiment: Experiment, variables: Mapping[str, Variable], timing: Timing) -> None:
        self.experiment = exp = experiment
        self.timing = timing
        self.episode_duration_s = exp.model.episode_duration
        self._variables = variables = with_elements(variables)  # array elements are scalar signals
        self.action_inputs = tuple(exp.actions.inputs)
        self.input_names, self.output_names, self.reference_names = task_signal_names(exp, variables)
        self.signal_names = self.output_names + self.input_names + self.reference_names
        self._index = {name: i for i, name in enumerate(self.signal_names)}
        self._signals: list[float] = [0.0] * len(self.signal_names)
        self._has_refs = False
        self.sampler = ScenarioSampler(exp, self.sample_times)
        self._build_actions()
        self._build_observations()
        user = load_callable(exp.reward.callable, "reward.callable") if exp.reward.callable else None
        self.reward = build_reward(exp.reward, self.signal_names, self.action_inputs, user)
        self._build_termination()
        self._episode_hook = load_callable(exp.hooks.episode, "hooks.episode") if exp.hooks.episode else None
        self.episode: EpisodeSpec | None = None
        self._repeat: list[float] | None = None  # the inputs a repeated episode starts from
        self._action_starts = [self._start(name) for name in self.action_inputs]  # the FMU's starts
        self._refs = np.zeros((1, len(self.reference_names)))
        self._no_columns = np.zeros((0, 0))
        self._profile_inputs = np.zeros((1, len(self.input_names) - len(self.action_inputs)))

    def sample_times(self, duration_s: float | None = None) -> FloatArray:
        """Times t_j of the samples of an episode (j = 0..N)."""
        n = round((duration_s or self.episode_duration_s) / self.timing.sampling_time_s + 1e-9)
        times: FloatArray = (
            self.timing.start_time_s + np.arange(n + 1, dtype=np.float64) * self.timing.sampling_time_s
        )
        return times

    # -- actions -----------------------------------------------------------------------------------
    def _build_actions(self) -> None:
        actions = self.experiment.actions
        n = len(self.action_inputs)
        self._kind = actions.type
        if actions.type == "continuous":
            bounds = [action_bounds(self.experiment, self._variables[name]) for name in self.action_inputs]
            low = np.array([b[0] for b in bounds], dtype=np.float64)
            high = np.array([b[1] for b in bounds], dtype=np.float64)
            self._a_centre = ((high + low) / 2).tolist()
            self._a_half_list = ((high - low) / 2).tolist()
            self.action_space: gym.Space[Any] = gym.spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)
        elif actions.type == "discrete":
            table = actions.table or [[v] for v in actions.levels[self.action_inputs[0]]]
            self._table_rows = [[float(v) for v in row] for row in table]
            self.action_space = gym.spaces.Discrete(len(table))
        else:
            self._levels = [np.array(actions.levels[name], dtype=np.float64) for name in self.action_inputs]
            self.action_space = gym.spaces.MultiDiscrete([len(levels) for levels in self._levels])
        noise = self.experiment.noise.actions
        self._action_noise = [(self.action_inputs.index(n), d) for n, d in noise.items()]
        self._action_noise_table: list[list[float]] = []
        self._inputs = [0.0] * len(self.input_names)
        self._previous_inputs = [0.0] * len(self.input_names)
        self._n_profiles = len(self.input_names) - n

    def action_to_inputs(self, action: Any, sample: int, rng: np.random.Generator) -> list[float]:
        """FMU input values (physical units) for sample ``sample``: action, actuator noise, profiles.

        Plain-Python floats on purpose: for a handful of values they beat numpy's per-call cost.
        """
        u = self._inputs
        self._previous_inputs[:] = u
        n = len(self.action_inputs)
        if self._kind == "continuous":
            values = action.tolist() if hasattr(action, "tolist") else list(action)
            if not isinstance(values, list) or len(values) != n:
                raise self._bad_action(action, sample)
            centre, half = self._a_centre, self._a_half_list
            for i, v in enumerate(values):
                if v - v != 0.0:
                    raise self._bad_action(action, sample)
                u[i] = centre[i] + half[i] * (-1.0 if v < -1.0 else 1.0 if v > 1.0 else v)
            if type(action) is ExactAction and action.physical is not None and len(action.physical) == n:
                u[:n] = action.physical
        elif self._kind == "discrete":
            u[:n] = self._discrete_row(action, sample)
        else:
            indices = np.asarray(action).reshape(-1)
            if indices.shape[0] != n or not all(
                0 <= int(i) < len(lv) for i, lv in zip(indices, self._levels)
            ):
                raise self._bad_action(action, sample)
            u[:n] = [float(lv[int(i)]) for i, lv in zip(indices, self._levels)]
        if self._action_noise:
            row = self._action_noise_table[min(sample, len(self._action_noise_table) - 1)]
            for k, (i, _) in enumerate(self._action_noise):
                u[i] += row[k]
        if self._n_profiles:
            u[n:] = self._profile_inputs[min(sample, len(self._profile_inputs) - 1)].tolist()
        return u

    def action_for_inputs(self, values: Any) -> Any:
        """The agent action whose physical input values are nearest ``values`` (one per action input).

        The inverse of the action mapping: continuous values are scaled into [-1, 1] (clipped),
        discrete ones pick the nearest level or table row. Baselines such as PID controllers
        compute physical inputs and use this to act through the same action space as agents.
        """
        u = np.asarray(values, dtype=np.float64).reshape(-1)
        if self._kind == "continuous":
            centre, half = np.asarray(self._a_centre), np.asarray(self._a_half_list)
            return np.clip((u - centre) / half, -1.0, 1.0).astype(np.float32)
        if self._kind == "discrete":
            rows = np.asarray(self._table_rows)
            return int(np.argmin(np.abs(rows - u).sum(axis=1)))
        return np.array([int(np.argmin(np.abs(levels - v))) for levels, v in zip(self._levels, u)])

    def _discrete_row(self, action: Any, sample: int) -> list[float]:
        try:
            index = int(action)
        except (TypeError, ValueError):
            raise self._bad_action(action, sample) from None
        if index != action or not 0 <= index < len(self._table_rows):
            raise self._bad_action(action, sample)
        return self._table_rows[index]

    @property
    def variables(self) -> Mapping[str, Variable]:
        """The model's variables, array elements included as scalars (``y[2]``)."""
        return self._variables

    @property
    def action_mapping(self) -> ActionMapping:
        """The action-to-input mapping (fixed for the task's life)."""
        noise = [i for i, _ in self._action_noise]
        if self._kind == "continuous":
            return ActionMapping(self._kind, self._a_centre, self._a_half_list, noise_columns=noise)
        if self._kind == "discrete":
            return ActionMapping(self._kind, table=self._table_rows, noise_columns=noise)
        return ActionMapping(self._kind, levels=self._levels, noise_columns=noise)

    def episode_tables(self) -> EpisodeTables:
        """The per-sample tables :meth:`new_episode` drew (references, profiles, noise)."""
        rows = len(self._refs)
        return EpisodeTables(
            self._refs,
            self._profile_inputs,
            _as_table(self._action_noise_table, rows),
            _as_table(self.observer.noise_table, rows),
        )

    def bad_output(self, outputs: list[float], sample: int) -> NonFiniteOutputs:
        """The error for non-finite ``outputs`` at ``sample`` (names the offending outputs)."""
        bad = [f"{n}={v}" for n, v in zip(self.output_names, outputs) if v - v != 0.0]
        return NonFiniteOutputs(
            f"non-finite outputs {', '.join(bad)} at sample {sample}: the model diverged "
            f"(check its parameters, the action bounds, or the step size {self.timing.step_size_s:g} s)"
        )

    def _bad_action(self, action: Any, sample: int) -> BridgeError:
        return BridgeError(
            f"invalid action {action!r} at sample {sample}: expected an element of {self.action_space} "
            f"(for {list(self.action_inputs)}); a NaN usually means the policy diverged"
        )

    # -- observations ------------------------------------------------------------------------------
    def _build_observations(self) -> None:
        self.observer = ObservationBuilder(self, self.experiment.observations, self._variables)
        self.observation_space = self.observer.space

    # -- termination -------------------------------------------------------------------------------
    def _build_termination(self) -> None:
        """``termination_reason(signals)`` as one generated conditional over the bounds."""
        from bridge.task.codegen import termination

        self.termination_reason = termination(self.experiment.termination.bounds, self._index)

    # -- episode life cycle --------------------------------------------------------------------------
    def new_episode(self, rng: np.random.Generator, scenario: str | None = None) -> EpisodeSpec:
        """Choose and draw the next episode (scenario, parameters, profiles) from ``rng``."""
        repeat = self._repeat
        if repeat is not None and scenario is None:
            # Nothing to choose or draw (see _repeatable): the last episode again, its tables kept.
            # A reset after an episode finds little in the caches, so touching less is what counts.
            self._inputs[:] = self._previous_inputs[:] = repeat
            return self.episode  # type: ignore[return-value]
        self._repeat = None
        spec = self.sampler.episode(rng, scenario)
        if self._episode_hook is not None:
            spec = self._episode_hook(spec, rng) or spec
        self.episode = spec
        n = spec.n_samples
        if len(self._no_columns) != n + 1:  # kept between episodes of one length: a reset stays cheap
            self._no_columns = np.zeros((n + 1, 0))
        self._refs = (
            np.column_stack([spec.references[r] for r in self.reference_names])
            if self.reference_names
            else self._no_columns
        )
        profile_names = self.input_names[len(self.action_inputs) :]
        self._profile_inputs = (
            np.column_stack(
                [spec.inputs.get(name, np.full(n + 1, self._start(name))) for name in profile_names]
            )
            if profile_names
            else self._no_columns
        )
        self._has_refs = bool(self.reference_names)
        self._inputs[len(self.action_inputs) :] = self._profile_inputs[0].tolist() if profile_names else []
        if spec.values:
            self._inputs[: len(self.action_inputs)] = [self._start(n) for n in self.action_inputs]
        else:  # no parameters or start values this episode: the inputs start at their FMU starts
            self._inputs[: len(self.action_inputs)] = self._action_starts
        self._previous_inputs[:] = self._inputs
        # Noise for the whole episode in one vectorised draw: per sample it is a lookup.
        self._action_noise_table = noise_table(self._action_noise, rng, n + 1) if self._action_noise else []
        self.observer.new_episode(rng, n + 1)
        if scenario is None and self._repeatable():
            self._repeat = list(self._inputs)
        return spec

    def _repeatable(self) -> bool:
        """Whether every next episode equals this one without a draw from the generator: one
        scenario taken without a choice, nothing drawn, no profile, no noise, no episode hook."""
        if self._episode_hook is not None or self._action_noise or self.observer.has_noise:
            return False
        return self.sampler.repeats()

    def _start(self, name: str) -> float:
        var = self._variables[name]
        if self.episode is not None and name in self.episode.values:
            return float(self.episode.values[name])
        return float(var.start) if isinstance(var.start, int | float) else 0.0

    @property
    def applied_inputs(self) -> list[float]:
        """The FMU input values of the current sample (physical units), live: read, do not modify.

        Filled by ``action_to_inputs`` (actions, actuator noise, scenario profiles); recorders and
        evaluation read it after each step without a copy."""
        return self._inputs

    @property
    def n_samples(self) -> int:
        return self.episode.n_samples if self.episode is not None else 0

    def initial_inputs(self) -> list[float]:
        """Input values at t_0 before any action (start values, profiles at t_0)."""
        return list(self._inputs)

    def fill_signals(self, outputs: list[float], sample: int) -> list[float]:
        """The signal vector [outputs | inputs | references at t_sample] as a list."""
        for value in outputs:
            if value - value != 0.0:  # NaN or infinity from the FMU: never pass it on silently
                raise self.bad_output(outputs, sample)
        s = outputs + self._inputs
        if self._has_refs:
            s += self._refs[min(sample, len(self._refs) - 1)].tolist()
        self._signals = s
        return s

    def first_observation(self, outputs: list[float], rng: np.random.Generator) -> npt.NDArray[np.float32]:
        signals = self.fill_signals(outputs, 0)
        self.reward.reset()
        return self.observer.reset(signals, self._inputs, rng)

    def observe(self, outputs: list[float], sample: int, rng: np.random.Generator) -> npt.NDArray[np.float32]:
        """The observation for outputs at sample ``sample`` without a reward (a deployed agent)."""
        if sample == 0:
            return self.first_observation(outputs, rng)
        return self.observer.observe(self.fill_signals(outputs, sample), self._inputs, rng)

    def step_result(
        self, outputs: list[float], sample: int, fmu_terminated: bool, rng: np.random.Generator
    ) -> tuple[npt.NDArray[np.float32], float, bool, bool, str | None]:
        """(observation, reward, terminated, truncated, reason) after the step into sample ``sample``."""
        signals = self.fill_signals(outputs, sample)
        reason = self.termination_reason(signals)
        if fmu_terminated and reason is None:
            reason = "fmu" if self.experiment.termination.on_fmu_terminate else None
        terminated = reason is not None
        truncated = not terminated and (sample >= self.n_samples or fmu_terminated)
        if truncated:
            reason = "fmu-truncated" if fmu_terminated else "time"
        reward = self.reward(signals, self._inputs, self._previous_inputs, terminated)
        obs = self.observer.observe(signals, self._inputs, rng)
        return obs, reward, terminated, truncated, reason

    @property
    def signal_values(self) -> list[float]:
        """The last signal vector [outputs | inputs | references] (``signal_names`` order), live."""
        return self._signals

    def signal_dict(self) -> dict[str, float]:
        """The last signals by name, exact (as the model computed them)."""
        return dict(zip(self.signal_names, self._signals))

    def controller_signals(self) -> dict[str, float]:
        """The last signals by name as a controller reads them: through the agent's sensors (the
        sensor noise of the observation just made) unless ``evaluation.baseline_signals`` is
        ``exact``. Every baseline on every path (evaluation, residual training, deployment) reads this."""
        if self.experiment.evaluation.baseline_signals == "exact":
            return self.signal_dict()
        return dict(zip(self.signal_names, self.observer.measured(self._signals)))


def _as_table(rows: list[list[float]], n: int) -> FloatArray:
    return np.array(rows, dtype=np.float64) if rows else np.zeros((n, 0))
