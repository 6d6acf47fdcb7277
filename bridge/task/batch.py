"""``BatchTask``: the Task of N envs at once, its per-step math evaluated with numpy over the batch.

Episodes are drawn by N scalar :class:`~bridge.task.core.Task` objects, one per env and each from
that env's own generator, so scenario choice, parameter draws and noise tables are exactly what
N single envs draw; the first observation of an episode is the scalar Task's own. Per step,
action mapping, the signal vector, termination, reward and observation run over the batch with
the sources the scalar Task generates (reward terms, observation elements) evaluated on columns.
Every operation is the same IEEE operation in the same order, so results are bit-identical to
the scalar Task on every CPU (the generated sources use only exactly rounded operations; see
:mod:`bridge.task.codegen`). Reward expressions and reward callables run per env on its row.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing
from bridge.fmu.vocab import Variable
from bridge.task.codegen import batch_observation, batch_reward_terms
from bridge.task.core import ExactAction, Task
from bridge.task.scenario import EpisodeSpec

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


class BatchTask:
    """The task side of ``n`` envs over one experiment (reasons: see :attr:`reasons`)."""

    def __init__(
        self, experiment: Experiment, variables: Mapping[str, Variable], timing: Timing, n: int
    ) -> None:
        if experiment.hooks.state:
            raise ConfigError("hooks.state: a batch cannot change model variables between steps; use FmuEnv")
        self.n = n
        self.tasks = [Task(experiment, variables, timing) for _ in range(n)]
        first = self.tasks[0]
        self.experiment, self.timing = experiment, timing
        self.action_inputs, self.input_names = first.action_inputs, first.input_names
        self.output_names, self.signal_names = first.output_names, first.signal_names
        self.action_space, self.observation_space = first.action_space, first.observation_space
        self._n_act, self._n_out = len(self.action_inputs), len(self.output_names)
        self._build_actions(first)
        self._build_step(first)
        self.inputs = np.zeros((n, len(self.input_names)))
        self.previous = np.zeros_like(self.inputs)
        self.signals = np.zeros((n, len(self.signal_names)))  # the last step's rows (step_result)
        self.n_samples = np.zeros(n, dtype=np.int64)
        self._rows = np.ones(n, dtype=np.int64)  # rows of each env's per-sample tables (samples + 1)
        self._tables: dict[str, FloatArray] = {}
        self.history = np.zeros((n, self._h, self._dim), dtype=np.float32)
        self._all = np.arange(n)

    # -- set-up -------------------------------------------------------------------------------------
    def _build_actions(self, task: Task) -> None:
        mapping = task.action_mapping
        self._kind = mapping.kind
        if self._kind == "continuous":
            self._centre, self._half = np.array(mapping.centre), np.array(mapping.half)
        elif self._kind == "discrete":
            self._table = np.array(mapping.table, dtype=np.float64)
        else:
            self._levels = mapping.levels
        self._noise_cols = mapping.noise_columns

    def _build_step(self, task: Task) -> None:
        exp, index = self.experiment, {name: i for i, name in enumerate(self.signal_names)}
        terms = exp.reward.terms
        self._terms = batch_reward_terms(terms, index, self.action_inputs) if terms else None
        self._expression, self._user = task.reward.expression, task.reward.user
        self._penalty = float(exp.reward.termination_penalty)
        observer = task.observer
        self._observe = batch_observation(observer.source)
        self._h, self._dim = observer.history_length, observer.dim
        self._obs_noise = observer.has_noise
        self._noise_signals = observer.noise_signals
        self._exact_signals = exp.evaluation.baseline_signals == "exact"
        self._obs_row: npt.NDArray[np.int64] | None = None
        self.reasons: list[str | None] = [None]  # reason code -> text; 0: running
        self._bounds: list[tuple[int, float, float, int]] = []
        for name, (lo, hi) in exp.termination.bounds.items():
            low = -np.inf if lo is None else float(lo)
            high = np.inf if hi is None else float(hi)
            self._bounds.append((index[name], low, high, len(self.reasons)))
            self.reasons.append(f"bounds:{name}")
        self._on_fmu = exp.termination.on_fmu_terminate
        self.reasons += ["fmu", "fmu-truncated", "time"]
        self._fmu, self._fmu_trunc, self._time = (
            len(self.reasons) - 3,
            len(self.reasons) - 2,
            len(self.reasons) - 1,
        )

    # -- episodes -----------------------------------------------------------------------------------
    def new_episode(self, i: int, rng: np.random.Generator, scenario: str | None = None) -> EpisodeSpec:
        """Draw env ``i``'s next episode from its generator (the scalar Task's own draw)."""
        task = self.tasks[i]
        spec = task.new_episode(rng, scenario)
        rows = spec.n_samples + 1
        tables = task.episode_tables()
        self._store(i, rows, "refs", tables.references)
        self._store(i, rows, "profiles", tables.profile_inputs)
        self._store(i, rows, "act_noise", tables.action_noise)
        self._store(i, rows, "obs_noise", tables.observation_noise)
        self._rows[i], self.n_samples[i] = rows, spec.n_samples
        return spec

    def _store(self, i: int, rows: int, key: str, table: FloatArray) -> None:
        """Keep env ``i``'s per-sample table in a padded (n, rows, columns) array."""
        held = self._tables.get(key)
        if held is None or held.shape[1] < rows:
            grown = np.zeros((self.n, max(rows, 1 if held is None else held.shape[1]), table.shape[1]))
            if held is not None:
                grown[:, : held.shape[1]] = held
            self._tables[key] = held = grown
        held[i, :rows] = table
        held[i, rows:] = table[-1] if rows else 0.0

    def initial_inputs(self, i: int) -> list[float]:
        return self.tasks[i].initial_inputs()

    def first_observation(
        self, i: int, outputs: list[float], rng: np.random.Generator
    ) -> npt.NDArray[np.float32]:
        """Env ``i``'s first observation (scalar Task), which also seeds its history and inputs."""
        task = self.tasks[i]
        obs = task.first_observation(outputs, rng)
        self.history[i] = obs.reshape(self._h, self._dim)
        self.inputs[i] = task.applied_inputs
        self.previous[i] = task.applied_inputs
        return obs

    # -- per step, over the batch ---------------------------------------------------------------------
    def _row(self, samples: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        return np.minimum(samples, self._rows - 1)

    def actions_to_inputs(self, actions: Any, samples: npt.NDArray[np.int64]) -> FloatArray:
        """FMU input values of every env for the sample ``samples[i]`` (physical units)."""
        self.previous[:] = self.inputs
        u, n = self.inputs, self._n_act
        if self._kind == "continuous":
            a = np.asarray(actions, dtype=np.float64).reshape(self.n, n)
            if not np.isfinite(a).all():
                raise self.bad_actions(actions, np.asarray(~np.isfinite(a).all(axis=1)))
            u[:, :n] = self._centre + self._half * np.clip(a, -1.0, 1.0)
            physical = actions.physical if type(actions) is ExactAction else None
            if physical is not None and len(physical) == self.n * n:  # every env's values, exactly
                u[:, :n] = np.asarray(physical, dtype=np.float64).reshape(self.n, n)
        elif self._kind == "discrete":
            index = np.asarray(actions).reshape(self.n)
            bad = np.asarray((index < 0) | (index >= len(self._table)) | (index != np.floor(index)))
            if bad.any():
                raise self.bad_actions(actions, bad)
            u[:, :n] = self._table[index.astype(np.int64)]
        else:
            levels_index = np.asarray(actions).reshape(self.n, n)
            sizes = np.array([len(levels) for levels in self._levels])
            bad = np.asarray(((levels_index < 0) | (levels_index >= sizes)).any(axis=1))
            if bad.any():
                raise self.bad_actions(actions, bad)
            for j, levels in enumerate(self._levels):
                u[:, j] = levels[levels_index[:, j].astype(np.int64)]
        row = self._row(samples)
        if self._noise_cols:
            u[:, self._noise_cols] += self._tables["act_noise"][self._all, row]
        if u.shape[1] > n:
            u[:, n:] = self._tables["profiles"][self._all, row]
        return u

    def bad_actions(self, actions: Any, bad: BoolArray) -> BridgeError:
        envs = np.flatnonzero(bad).tolist()
        return BridgeError(
            f"invalid actions for envs {envs[:10]}: {np.asarray(actions)[envs[:3]].tolist()}; "
            f"expected elements of {self.action_space} (for {list(self.action_inputs)}); "
            "a NaN usually means the policy diverged"
        )

    def step_result(
        self, outputs: FloatArray, samples: npt.NDArray[np.int64], fmu_terminated: BoolArray
    ) -> tuple[npt.NDArray[np.float32], FloatArray, BoolArray, BoolArray, npt.NDArray[np.int64], BoolArray]:
        """(obs, reward, terminated, truncated, reason codes, non-finite rows) after stepping into
        ``samples`` (per env); reason codes index :attr:`reasons`. Rows flagged non-finite hold
        garbage: the env reports them as the plant's error."""
        row = self._row(samples)
        s = np.concatenate([outputs, self.inputs, self._tables["refs"][self._all, row]], axis=1)
        self.signals = s  # [outputs | inputs | references] per env, in ``signal_names`` order
        bad: BoolArray = np.asarray(~np.isfinite(outputs).all(axis=1))
        code = np.zeros(self.n, dtype=np.int64)
        for i, low, high, reason in reversed(self._bounds):
            x = s[:, i]
            code[~((low <= x) & (x <= high))] = reason
        if self._on_fmu:
            code[(code == 0) & fmu_terminated] = self._fmu
        terminated: BoolArray = code != 0
        truncated: BoolArray = ~terminated & ((samples >= self.n_samples) | fmu_terminated)
        code[truncated] = np.where(fmu_terminated[truncated], self._fmu_trunc, self._time)
        reward = self._reward(s, terminated, bad)
        obs = self._observations(s, row)
        return obs, reward, terminated, truncated, code, bad

    def _reward(self, s: FloatArray, terminated: BoolArray, bad: BoolArray) -> FloatArray:
        st = s.T
        total = np.zeros(self.n)
        if self._terms is not None:
            value = self._terms(st, self.inputs.T, self.previous.T)
            total = value if isinstance(value, np.ndarray) else np.full(self.n, float(value))
        if self._expression is not None or self._user is not None:
            total = total.copy()
            names = self.signal_names
            for i in np.flatnonzero(~bad).tolist():
                row = s[i].tolist()
                if self._expression is not None:
                    total[i] += self._expression(row)
                if self._user is not None:
                    total[i] += _number(self._user(dict(zip(names, row))))
        if self._penalty or terminated.any():
            total = np.where(terminated, total + self._penalty, total)
        return total

    def follow_scalar_step(self, samples: npt.NDArray[np.int64]) -> None:
        """After a batch of one stepped through its scalar Task: take its signal row and the
        observation's noise row, as :meth:`step_result` would have left them."""
        self.signals[0] = self.tasks[0].signal_values
        self._obs_row = self._row(samples)

    def controller_signals(self) -> FloatArray:
        """Every env's last signals as controllers read them, one row per env: the scalar
        :meth:`Task.controller_signals` over the batch (the sensor noise of the last observation)."""
        if self._exact_signals or not self._obs_noise or self._obs_row is None:
            return self.signals
        out: FloatArray = self.signals.copy()
        out[:, self._noise_signals] += self._tables["obs_noise"][self._all, self._obs_row]
        return out

    def _observations(self, s: FloatArray, row: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        self._obs_row = row
        nz = self._tables["obs_noise"][self._all, row].T if self._obs_noise else None
        columns = self._observe(s.T, self.inputs.T, nz)
        new = np.stack(columns, axis=1).astype(np.float32) if columns else np.zeros((self.n, 0), np.float32)
        if self._h == 1:
            self.history[:, 0] = new
        else:
            self.history[:, :-1] = self.history[:, 1:]
            self.history[:, -1] = new
        stacked: npt.NDArray[np.float32] = self.history.reshape(self.n, -1).copy()
        return stacked


def _number(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise BridgeError(f"reward.callable returned {value!r}; expected a number") from exc
