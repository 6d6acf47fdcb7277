"""Evaluation through the batch env: all episodes of a cell (agent x scenario) at once.

Episode ``j`` of a cell runs in env ``j`` of a :class:`~bridge.env.batch.BatchEnv` (one native
call steps every FMU), seeded exactly as ``run_episode`` seeds its ``FmuEnv``, so the traces and
metrics are those of the one-env-at-a-time path. Each env has its own policy object (a PID keeps
state); a trained SB3 model without a residual acts on the whole batch in one ``predict`` call.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from agents.evaluate_cell import Cell, baseline_settings, metric_spec
from agents.metrics import Trace, compute
from agents.policies import Policy, Sb3Policy, episode_stats, make_policy
from bridge.env.batch import BatchEnv
from bridge.experiment.config import Experiment, load_experiment
from bridge.task.core import ExactAction

CHUNK = 1024  # episodes per batch


def run_cell_batch(cell: Cell) -> tuple[list[dict[str, Any]], list[Trace], None]:
    """Worker entry point: every episode of one agent on one scenario, in batches of ``CHUNK``."""
    experiment = load_experiment(cell.experiment, version=cell.version)
    spec = metric_spec(experiment)
    traces: list[Trace] = []
    engines: dict[int, BatchEnv] = {}  # one per chunk size: the FMU instances serve every chunk
    try:
        for start in range(0, len(cell.seeds), CHUNK):
            seeds = cell.seeds[start : start + CHUNK]
            engine = engines.get(len(seeds))
            if engine is None:
                engine = engines[len(seeds)] = BatchEnv(experiment, len(seeds), autoreset=False)
            traces += _run(engine, _policies(cell, experiment, len(seeds)), seeds, cell.scenario)
    finally:
        for engine in engines.values():
            engine.close()
    rows = [
        {
            "agent": cell.agent_name,
            "scenario": trace.scenario,
            "episode": episode,
            "seed": seed,
            **compute(trace, spec),
        }
        for episode, (seed, trace) in enumerate(zip(cell.seeds, traces))
    ]
    return rows, traces, None


def _policies(cell: Cell, experiment: Experiment, n: int) -> list[Policy]:
    baselines = baseline_settings(experiment)
    first = make_policy(cell.agent, baselines, name=cell.agent_name)
    if isinstance(first, Sb3Policy) and not first.residual:
        return [first]  # stateless: one model acts on the batch
    return [first] + [make_policy(cell.agent, baselines, name=cell.agent_name) for _ in range(n - 1)]


def _run(engine: BatchEnv, policies: list[Policy], seeds: Sequence[int], scenario: str | None) -> list[Trace]:
    task, plant, n = engine.task, engine.plant, engine.n
    obs, infos = engine.reset_all(list(seeds), [scenario] * n)
    for i, policy in enumerate(policies):
        policy.reset(task.tasks[i], seeds[i])
    signals = np.array([list(t.controller_signals().values()) for t in task.tasks])
    timing = plant.timing
    times, rows, inputs, rewards = [timing.start_time_s + plant.k * timing.step_size_s], [signals], [], []
    reasons: list[Any] = [None] * n
    ended_terminated = np.zeros(n, dtype=bool)
    actions = _act(policies, obs, signals, names=task.signal_names, active=engine.active, previous=None)
    while engine.active.any():
        obs, reward, terminated, _, ended = engine.step(actions)
        inputs.append(task.inputs[:, : len(task.action_inputs)].copy())
        rewards.append(reward.copy())
        times.append(timing.start_time_s + plant.k * timing.step_size_s)
        rows.append(task.signals.copy())  # the exact signals: metrics score the true plant
        for i, end in ended.items():
            reasons[i], ended_terminated[i] = end["final_info"]["reason"], bool(terminated[i])
        if engine.active.any():
            actions = _act(
                policies,
                obs,
                task.controller_signals(),
                names=task.signal_names,
                active=engine.active,
                previous=actions,
            )
    traces = _traces(
        engine,
        infos,
        times=times,
        rows=rows,
        inputs=inputs,
        rewards=rewards,
        reasons=reasons,
        terminated=ended_terminated,
    )
    if len(policies) == len(traces):  # one policy object per env: its own counts
        for trace, policy in zip(traces, policies):
            trace.extra.update(episode_stats(policy))
    return traces


def _act(
    policies: list[Policy], obs: Any, signals: Any, *, names: Sequence[str], active: Any, previous: Any
) -> Any:
    if len(policies) == 1 and len(active) > 1:
        return policies[0].act(obs, {})  # a batched SB3 model (no signals needed)
    chosen = list(previous) if previous is not None else [None] * len(active)
    for i in np.flatnonzero(active).tolist():
        chosen[i] = policies[i].act(obs[i], dict(zip(names, signals[i].tolist())))
    return _exact(chosen)


def _exact(chosen: list[Any]) -> Any:
    """The envs' actions as one array; an ExactAction carrying every env's physical values when
    each env's action carries its own (fixed policies), so that they reach the FMUs exactly."""
    rows = np.array(chosen)
    if rows.ndim != 2:
        return rows
    width, physical = rows.shape[1], []
    for i, action in enumerate(chosen):
        own = action.physical if type(action) is ExactAction else None
        if own is not None and len(own) == width:
            physical += own
        elif own is not None and len(own) == len(chosen) * width:  # an ended env's row of the last batch
            physical += own[i * width : (i + 1) * width]
        else:
            return rows
    return ExactAction(rows, physical)


def _traces(
    engine: BatchEnv,
    infos: list[dict[str, Any]],
    *,
    times: list[Any],
    rows: list[Any],
    inputs: list[Any],
    rewards: list[Any],
    reasons: list[Any],
    terminated: Any,
) -> list[Trace]:
    task = engine.task
    time_s, table, u, r = np.array(times), np.array(rows), np.array(inputs), np.array(rewards)
    traces = []
    for i in range(engine.n):
        length = int(engine.samples[i])
        traces.append(
            Trace(
                time_s=time_s[: length + 1, i],
                signals={name: table[: length + 1, i, j] for j, name in enumerate(task.signal_names)},
                inputs={name: u[:length, i, j] for j, name in enumerate(task.action_inputs)},
                rewards=r[:length, i],
                reason=reasons[i],
                terminated=bool(terminated[i]),
                scenario=infos[i].get("scenario") or "nominal",
            )
        )
    return traces
