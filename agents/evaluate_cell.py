"""One cell of the evaluation grid (an agent on a scenario over a list of seeds) and what every
engine that runs one reads from the experiment: its metrics and its baselines."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.metrics import MetricSpec
from bridge.experiment.config import Experiment


@dataclass(frozen=True)
class Cell:
    experiment: Path
    version: str | None
    agent: str
    agent_name: str
    scenario: str | None
    seeds: tuple[int, ...]
    record_dir: Path | None


def metric_spec(experiment: Experiment) -> MetricSpec:
    """Metrics from ``evaluation.metrics``; tracking pairs default to the reward's tracking terms."""
    config = experiment.evaluation.metrics
    tracking = list(config.tracking) or [
        (t.tracking.output, t.tracking.reference) for t in experiment.reward.terms if t.tracking
    ]
    from bridge.task.core import load_callable

    return MetricSpec(
        tracking=tracking,
        effort=list(experiment.actions.inputs if config.effort is None else config.effort),
        constraints=dict(config.constraints),
        success=config.success,
        user=[load_callable(path, "evaluation.metrics.user") for path in config.user],
        band=config.settling_band,
        duration_s=experiment.model.episode_duration,
        scenario_durations={
            name: sc.episode_duration for name, sc in experiment.scenarios.items() if sc.episode_duration
        },
    )


def baseline_settings(experiment: Experiment) -> dict[str, dict[str, Any]]:
    """``evaluation.baselines`` as the keys each gives (what ``make_policy`` takes)."""
    return {name: spec.settings() for name, spec in experiment.evaluation.baselines.items()}
