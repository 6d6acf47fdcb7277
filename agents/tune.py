"""``fmu-bridge tune``: tune a baseline's gains or weights on the training scenarios.

Objective (stated with every result), a mean over the training scenarios and the seeds 1000,
1001, .. (never the evaluation seeds 0.. nor the held-out scenarios) of, per episode: ``held_iae``
the held IAE of the first tracking pair (``evaluation.metrics.tracking``, else the reward's) plus
``penalty`` if the episode terminates early (left its envelope); or ``return`` minus the episode
return, the task's own reward (what a trained agent maximises on the same scenarios, with its
effort or rate terms and termination penalty). Nelder-Mead searches the logarithms of the
chosen parameters (they stay positive and are searched relative to their size), starting from
the experiment's values. The result is written into a copy of the experiment (``--write``) and
as ``tuning.json`` (objective, parameters, start and best values, every evaluation, wall time).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate import run_episode
from agents.evaluate_cell import baseline_settings, metric_spec
from agents.metrics import compute
from agents.policies import baseline
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, load_experiment

TRAINING_SEED = 1000


@dataclass
class TuneResult:
    baseline: str
    parameters: list[str]
    start: list[float]
    best: list[float]
    start_objective: float
    best_objective: float
    objective: str
    scenarios: list[str]
    seeds: list[int]
    evaluations: list[dict[str, Any]] = field(default_factory=list)
    wall_time_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def get_path(settings: dict[str, Any], key: str) -> float:
    node: Any = settings
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            raise ConfigError(
                f"tune: {key!r} is not a value of the baseline; its keys: {sorted(_flat(settings))}"
            )
        node = node[part]
    if not isinstance(node, int | float) or isinstance(node, bool) or node <= 0:
        raise ConfigError(f"tune: {key!r} is {node!r}; only positive numbers are tuned (in log space)")
    return float(node)


def set_path(settings: dict[str, Any], key: str, value: float) -> dict[str, Any]:
    out: dict[str, Any] = copy.deepcopy(settings)
    node = out
    *parents, last = key.split(".")
    for part in parents:
        node = node[part]
    node[last] = value
    return out


def _flat(settings: dict[str, Any], prefix: str = "") -> list[str]:
    keys = []
    for key, value in settings.items():
        if isinstance(value, dict):
            keys += _flat(value, f"{prefix}{key}.")
        elif isinstance(value, int | float) and not isinstance(value, bool):
            keys.append(f"{prefix}{key}")
    return keys


def training_scenarios(experiment: Experiment) -> list[str | None]:
    held_out = set(experiment.evaluation.scenarios or experiment.schedule.evaluation)
    chosen = list(experiment.schedule.training) or [s for s in experiment.scenarios if s not in held_out]
    return list(chosen) or [None]


def tune(
    experiment_path: Path,
    name: str,
    parameters: Sequence[str],
    *,
    iterations: int = 100,
    seeds: int = 2,
    penalty: float = 100.0,
    objective: str = "held_iae",
    version: str | None = None,
    log: Any = None,
) -> TuneResult:
    """Nelder-Mead over the log of ``parameters`` of the baseline ``name``; see the module doc."""
    from bridge.control.deps import require

    minimize = require("scipy.optimize", "fmu-bridge tune (Nelder-Mead)").minimize
    started = time.perf_counter()
    experiment = load_experiment(experiment_path, version=version)
    settings = baseline_settings(experiment)
    if name not in settings:
        raise ConfigError(
            f"tune: {name!r} is not in evaluation.baselines ({sorted(settings) or 'none defined'})"
        )
    base = settings[name]
    if not parameters:
        raise ConfigError(f"tune: name the values to tune with --param; {name} has {sorted(_flat(base))}")
    start = [get_path(base, key) for key in parameters]
    spec = metric_spec(experiment)
    if not spec.tracking:
        raise ConfigError("tune: the objective needs a tracking pair (evaluation.metrics.tracking)")
    output = spec.tracking[0][0]
    if objective not in ("held_iae", "return"):
        raise ConfigError(f"tune: objective {objective!r} is unknown; use held_iae or return")
    scenarios = training_scenarios(experiment)
    seed_list = [TRAINING_SEED + i for i in range(seeds)]
    env = FmuEnv(experiment)
    result = TuneResult(
        baseline=name, parameters=list(parameters), start=start, best=start, start_objective=np.nan,
        best_objective=np.nan, scenarios=[s or "" for s in scenarios], seeds=seed_list,
        objective=(
            f"mean held IAE of {output}, plus {penalty:g} per episode that terminates,"
            if objective == "held_iae" else "minus the mean episode return"
        ) + f" over {len(scenarios)} training scenarios x seeds {seed_list[0]}..{seed_list[-1]}",
    )  # fmt: skip

    def cost(log_values: np.ndarray) -> float:
        values = [float(v) for v in np.exp(log_values)]
        config = base
        for key, value in zip(parameters, values):
            config = set_path(config, key, value)
        policy = baseline(name, config)
        total, count = 0.0, 0
        for scenario in scenarios:
            for seed in seed_list:
                trace = run_episode(env, policy, seed, scenario)
                if objective == "return":
                    total -= float(np.sum(trace.rewards))
                else:
                    held = compute(trace, spec)[f"{output}.iae_held"]
                    total += float(held) + (penalty if trace.terminated else 0.0)
                count += 1
        value = total / count
        result.evaluations.append({"values": values, "objective": value})
        if log is not None:
            log(f"{len(result.evaluations):4d}  {value:10.4f}  " + "  ".join(f"{v:.5g}" for v in values))
        return value

    try:
        x0 = np.log(np.asarray(start))
        result.start_objective = cost(x0)
        found = minimize(
            cost, x0, method="Nelder-Mead",
            options={"maxfev": iterations, "xatol": 1e-3, "fatol": 1e-4, "initial_simplex": _simplex(x0)},
        )  # fmt: skip
    finally:
        env.close()
    best = min(result.evaluations, key=lambda e: e["objective"])
    result.best, result.best_objective = best["values"], best["objective"]
    del found
    result.wall_time_s = time.perf_counter() - started
    return result


def _simplex(x0: np.ndarray) -> np.ndarray:
    """Start steps of a factor 2 in each parameter (log space)."""
    return np.vstack([x0, x0 + np.log(2.0) * np.eye(len(x0))])


def write_experiment(experiment_path: Path, result: TuneResult, target: Path) -> Path:
    """A copy of the experiment file with the tuned values in the baseline (comments are not kept)."""
    import yaml

    from bridge.experiment.yaml_text import read_yaml

    data = read_yaml(experiment_path)
    section = data["evaluation"]["baselines"][result.baseline]
    for key, value in zip(result.parameters, result.best):
        node = section
        *parents, last = key.split(".")
        for part in parents:
            node = node[part]
        node[last] = float(f"{value:.6g}")
    note = (
        f"# evaluation.baselines.{result.baseline} tuned by `fmu-bridge tune`: {result.objective}; "
        f"{result.start_objective:.4g} -> {result.best_objective:.4g} "
        f"in {len(result.evaluations)} evaluations\n"
    )
    target.write_text(note + yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    load_experiment(target)  # what was written is a valid experiment
    return target
