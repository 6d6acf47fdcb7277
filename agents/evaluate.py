"""Evaluation: the grid scenario x agent x episode, in parallel worker processes.

Every agent sees the same seeds on the same scenarios, so differences are the agents'. Each
cell (agent, scenario) runs in a worker process with its own env (the FMU opened there) and
returns one metrics row per episode plus the traces for plots.
"""

from __future__ import annotations

import logging
import multiprocessing
import re
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate_cell import Cell, baseline_settings, metric_spec
from agents.metrics import Trace, compute
from agents.policies import Policy, episode_stats, make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment

_log = logging.getLogger(__name__)
NOMINAL = "nominal"  # the scenario of an experiment that defines none (the sampler's name)


@dataclass
class EvaluationResult:
    rows: list[dict[str, Any]]
    traces: dict[tuple[str, str], list[Trace]] = field(default_factory=dict)
    agents: list[str] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)
    recordings: list[Path] = field(default_factory=list)


def run_episode(env: Any, policy: Policy, seed: int, scenario: str | None) -> Trace:
    """One episode of ``policy``; the trace holds every task signal in physical units."""
    task = env.unwrapped.task
    obs, info = env.reset(seed=seed, options={"scenario": scenario} if scenario else None)
    name = info.get("scenario") or scenario or NOMINAL
    policy.reset(task, seed)
    times, rows, inputs, rewards = [info["time_s"]], [list(task.signal_dict().values())], [], []
    terminated, reason = False, None
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, task.controller_signals()))
        inputs.append(list(task.applied_inputs[: len(task.action_inputs)]))
        rewards.append(float(reward))
        times.append(info["time_s"])
        rows.append(list(task.signal_dict().values()))
        if terminated or truncated:
            reason = info.get("reason")
            break
    table = np.array(rows)
    u = np.array(inputs)
    return Trace(
        time_s=np.array(times),
        signals={name: table[:, i] for i, name in enumerate(task.signal_names)},
        inputs={name: u[:, i] for i, name in enumerate(task.action_inputs)},
        rewards=np.array(rewards),
        reason=reason,
        terminated=terminated,
        scenario=name,
        extra=episode_stats(policy),
    )


def run_cell(
    cell: Cell, on_episode: Callable[[], None] | None = None
) -> tuple[list[dict[str, Any]], list[Trace], Path | None]:
    """Worker entry point: every episode of one agent on one scenario (``on_episode`` after each)."""
    experiment = load_experiment(cell.experiment, version=cell.version)
    policy = make_policy(cell.agent, baseline_settings(experiment), name=cell.agent_name)
    spec = metric_spec(experiment)
    env: Any = FmuEnv(experiment)
    recording = None
    if cell.record_dir is not None:
        env, recording = _record(env, cell)
    rows, traces = [], []
    try:
        for episode, seed in enumerate(cell.seeds):
            trace = run_episode(env, policy, seed, cell.scenario)
            rows.append(
                {
                    "agent": cell.agent_name,
                    "scenario": trace.scenario,
                    "episode": episode,
                    "seed": seed,
                    **compute(trace, spec),
                }
            )
            traces.append(trace)
            if on_episode is not None:
                on_episode()
    finally:
        env.close()
    return rows, traces, recording


def _record(env: Any, cell: Cell) -> tuple[Any, Path | None]:
    try:
        from bridge.recording.env_recorder import record_env
    except ImportError:  # recording support not available in this installation
        return env, None
    assert cell.record_dir is not None
    wrapped = record_env(
        env,
        directory=cell.record_dir,
        run_name=f"{cell.agent_name}__{cell.scenario or 'nominal'}",  # the scenario sampler's name
        agent=cell.agent,
    )
    return wrapped, Path(getattr(wrapped, "path", cell.record_dir))


def evaluate(
    agents: Sequence[str],
    experiment_path: Path,
    *,
    version: str | None = None,
    scenarios: Sequence[str] | None = None,
    episodes: int | None = None,
    workers: int = 1,
    seed: int = 0,
    record_dir: Path | None = None,
    batch: bool = False,
    progress: Callable[[int, int], None] | None = None,
    engine: str = "local",
    chunk_episodes: int = 4,
    ray_address: str | None = None,
) -> EvaluationResult:
    """Evaluate every agent on every scenario for ``episodes`` seeded episodes.

    ``batch``: run all episodes of a cell at once in a batch env (``agents.evaluate_batch``):
    the same seeds and results, a large grid in seconds; no recordings. ``progress(done, total)``
    is called with the episodes done (after each episode in this process, after each agent and
    scenario with worker processes or a batch, at the end with Ray).
    ``engine="ray"``: each cell in chunks of ``chunk_episodes`` episodes as Ray tasks on the
    cluster at ``ray_address`` (``agents.ray_engine``): the same seeds and results; no recordings."""
    if engine not in ("local", "ray"):
        raise ConfigError(f"engine must be 'local' or 'ray', got {engine!r}")
    if batch and record_dir is not None:
        raise ConfigError("evaluate --batch does not record episodes; pass --no-record (or drop --batch)")
    if engine == "ray" and record_dir is not None:
        raise ConfigError(
            "evaluate --engine ray does not record episodes (they run on other machines); pass --no-record"
        )
    experiment = load_experiment(experiment_path, version=version)
    config = experiment.evaluation
    agents, names = _named(agents)
    chosen: list[str | None] = list(
        scenarios or config.scenarios or experiment.schedule.evaluation or experiment.scenarios
    )
    unknown = [s for s in chosen if s not in experiment.scenarios]
    if unknown:
        raise ConfigError(
            f"scenarios {unknown} are not defined in {experiment_path}; "
            f"defined: {sorted(experiment.scenarios) or 'none'}"
        )
    n = episodes or config.episodes
    seeds = tuple(seed + i for i in range(n))
    cells = [
        Cell(experiment_path.resolve(), version, spec, name, sc, seeds, record_dir)
        for spec, name in zip(agents, names)
        for sc in (chosen or [None])
    ]
    # no scenarios defined: every episode is the sampler's "nominal" one
    result = EvaluationResult(rows=[], agents=names, scenarios=[c or NOMINAL for c in chosen] or [NOMINAL])
    if engine == "ray":
        from agents.evaluate_batch import CHUNK
        from agents.ray_engine import licence_resources, map_cells

        instances = min(chunk_episodes, CHUNK) if batch else 1  # FMU instances a chunk opens at once
        outcomes: list[Any] = map_cells(
            cell_runner(batch),
            cells,
            episodes_per_chunk=chunk_episodes,
            address=ray_address,
            resources=licence_resources(experiment, instances),
        )
        if progress is not None:
            total = sum(len(c.seeds) for c in cells)
            progress(total, total)
    else:
        outcomes = _map(cells, workers, batch, progress)
    for cell, (rows, traces, recording) in zip(cells, outcomes):
        result.rows += rows
        result.traces[(cell.agent_name, cell.scenario or NOMINAL)] = traces
        if recording is not None:
            result.recordings.append(recording)
    return result


def cell_runner(batch: bool) -> Any:
    """The function that runs one cell: ``run_cell``, or its batch env twin."""
    if batch:
        from agents.evaluate_batch import run_cell_batch

        return run_cell_batch
    return run_cell


def _map(
    cells: list[Cell],
    workers: int,
    batch: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> list[tuple[list[dict[str, Any]], list[Trace], Path | None]]:
    total = sum(len(c.seeds) for c in cells)
    done = 0

    def tick(episodes: int = 1) -> None:
        nonlocal done
        done += episodes
        if progress is not None:
            progress(done, total)

    if progress is not None:
        progress(0, total)
    run: Any = cell_runner(batch)
    if workers <= 1 or len(cells) == 1:
        results = []
        for c in cells:
            results.append(run(c) if batch else run_cell(c, tick))
            if batch:
                tick(len(c.seeds))
        return results
    context = multiprocessing.get_context("spawn")  # a fresh process per worker: no inherited FMU state
    with ProcessPoolExecutor(max_workers=min(workers, len(cells)), mp_context=context) as pool:
        results = []
        for c, result in zip(cells, pool.map(run, cells)):
            results.append(result)
            tick(len(c.seeds))
        return results


def agent_names(agents: Sequence[str]) -> list[str]:
    """The names the agents get in tables and plots (``NAME=SPEC``, the run or model, the word)."""
    return _named(agents)[1]


def _named(agents: Sequence[str]) -> tuple[list[str], list[str]]:
    """Agent specs and their names: ``NAME=SPEC`` names an agent (``residual=runs/r/model.zip``),
    otherwise the name comes from the run directory, the model file or the baseline word."""
    specs, given = [], []
    for agent in agents:
        name, sep, spec = agent.partition("=")
        named = bool(sep) and bool(spec) and re.fullmatch(r"[\w.+-]+", name) is not None
        specs.append(spec if named else agent)
        given.append(name if named else None)
    derived = _agent_names(specs)
    names = [g or d for g, d in zip(given, derived)]
    if len(set(names)) < len(names):
        raise ConfigError(f"agents need distinct names; got {names}")
    return specs, names


def _agent_names(agents: Sequence[str]) -> list[str]:
    names: list[str] = []
    for spec in agents:
        path = Path(spec)
        base = path.name if path.is_dir() else path.stem if path.suffix == ".zip" else spec
        name, i = base, 2
        while name in names:
            name, i = f"{base}-{i}", i + 1
        names.append(name)
    return names
