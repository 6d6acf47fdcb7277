"""``fmu-bridge check`` and ``fmu-bridge scenarios``: reports a person reads before training."""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from bridge.cli.simulate import make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.env.plants import model_info_for
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.validate import check_experiment, timing
from bridge.task.core import Task
from bridge.task.fixed import is_fixed_policy, unknown_policy
from bridge.task.scenario import describe


def check_and_report(
    path: Path, *, version: str | None, steps: int, console: Console, policy: str = "zero"
) -> None:
    """Validate, run both env checkers, and print spaces and a few steps of the fixed ``policy``."""
    from gymnasium.utils.env_checker import check_env as gym_check

    if not is_fixed_policy(policy):  # before the FMU is loaded
        raise ConfigError(unknown_policy(policy))
    experiment = load_experiment(path, version=version)
    info = check_experiment(experiment, model_info_for(experiment))
    console.print(
        f"[green]config ok[/green]: {path} (version {experiment.version}) against {info.model_name}"
    )
    with FmuEnv(experiment) as env, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check(env, skip_render_check=True)
        console.print("[green]gymnasium env checker passed[/green]")
        checkers = _plugin_checkers()
        if not checkers:
            console.print("stable-baselines3's env checker is not available: pip install 'fmu-bridge[train]'")
        for name, checker in checkers:
            checker(env)
            console.print(f"[green]{name} env checker passed[/green]")
        for warning in caught:
            if "infinity" not in str(warning.message):  # unbounded observations are deliberate
                console.print(f"[yellow]warning:[/yellow] {escape(str(warning.message))}")
        t = env.timing
        console.print(f"action space: {env.action_space}\nobservation space: {env.observation_space}")
        console.print(f"observation: {env.task.observer.names}")
        console.print(
            f"FMU step {t.step_size_s:g} s x {t.steps_per_sample} = sample {t.sampling_time_s:g} s; "
            f"episode {env.task.episode_duration_s:g} s"
        )
        _few_steps(env, steps, console, policy)


def _plugin_checkers() -> list[tuple[str, Callable[[Any], None]]]:
    """Env checkers contributed by other packages (``agents`` adds stable-baselines3's)."""
    found = []
    for entry in entry_points(group="fmu_bridge.env_checkers"):
        try:
            found.append((entry.name, entry.load()))
        except ImportError:
            continue
    return found


def _few_steps(env: FmuEnv, steps: int, console: Console, spec: str) -> None:
    policy = make_policy(spec, env.task, 0)
    obs, info = env.reset(seed=0)
    title = f"first steps ({spec} action, scenario {info['scenario']})"
    header = [escape(h) for h in ("step", "t [s]", *env.output_names, "reward")]  # "[s]" is not markup
    rows = []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        rows.append(
            [
                str(info["step"]),
                f"{info['time_s']:g}",
                *(f"{v:.4g}" for v in info["outputs"]),
                f"{float(reward):.4g}",
            ]
        )
        if terminated or truncated:
            break
    if len(header) * _CELL_WIDTH <= console.width:
        table = Table(*header, title=title)
        for row in rows:
            table.add_row(*row)
    else:  # too many signals for a column each: a row each, a column per step
        table = Table("step", *(row[0] for row in rows), title=title)
        for i, name in enumerate(header[1:], start=1):
            table.add_row(name, *(row[i] for row in rows))
    console.print(table)


#: Characters a column of the first-steps table needs to show a name or a value whole.
_CELL_WIDTH = 11


def scenario_data(path: Path, *, sample: int, seed: int) -> dict[str, Any]:
    """The scenarios of an experiment, its schedule and ``sample`` drawn episodes, as plain data."""
    experiment = load_experiment(path)
    info = check_experiment(experiment, model_info_for(experiment))
    task = Task(experiment, info.variables, timing(experiment, info))
    sampler = task.sampler
    scenarios = []
    for name in sampler.names:
        sc = experiment.scenarios.get(name)
        use = "evaluation" if name in sampler.evaluation else "training" if name in sampler.training else "-"
        scenarios.append(
            {
                "scenario": name,
                "use": use,
                "description": sc.description if sc else "",
                "parameters": {k: float(v) for k, v in sc.parameters.items()} if sc else {},
                "references": list(sc.references) if sc else [],
                "inputs": list(sc.inputs) if sc else [],
            }
        )
    episodes = []
    rng = np.random.default_rng(seed)
    for i in range(sample):
        d = describe(task.new_episode(rng))
        episodes.append(
            {
                "episode": i,
                "scenario": d["scenario"],
                "drawn": {k: float(v) for k, v in d["drawn"].items()},
                "references": {k: [float(a), float(b)] for k, (a, b) in d["references"].items()},
            }
        )
    return {"scenarios": scenarios, "schedule": experiment.schedule.mode, "seed": seed, "episodes": episodes}


def scenario_report(path: Path, *, sample: int, seed: int, console: Console, as_json: bool = False) -> None:
    """``fmu-bridge scenarios``: a table where it fits (names never cut when piped), or JSON."""
    from bridge.cli.inspect import print_rows

    data = scenario_data(path, sample=sample, seed=seed)
    if as_json:
        print(json.dumps(data, indent=2))  # plain: for programs, never wrapped or coloured
        return
    columns = ["scenario", "use", "description", "parameters", "references", "inputs"]
    rows = [
        [sc["scenario"], sc["use"], sc["description"], str(sc["parameters"]) if sc["parameters"] else "",
         ", ".join(sc["references"]), ", ".join(sc["inputs"])]
        for sc in data["scenarios"]
    ]  # fmt: skip
    print_rows(console, columns, rows)
    console.print(f"schedule: {data['schedule']}")
    if sample:
        drawn = [
            [str(e["episode"]), e["scenario"], ", ".join(f"{k}={v:.4g}" for k, v in e["drawn"].items()),
             ", ".join(f"{k}: {a:g} -> {b:g}" for k, (a, b) in e["references"].items())]
            for e in data["episodes"]
        ]  # fmt: skip
        columns = ["episode", "scenario", "drawn values", "references (t0 -> end)"]
        print_rows(console, columns, drawn, f"{sample} sampled episodes (seed {seed})")
