"""The experiment's FMU as a ``Model``: one place that maps the ``model`` section to its settings."""

from __future__ import annotations

from pathlib import Path

from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing
from bridge.fmu import Model


def experiment_model(
    experiment: Experiment, fmu_path: Path, t: Timing, instance_name: str | None = None
) -> Model:
    """An instance of the experiment's FMU with its ``model`` section's settings (interface, reset
    policy, tolerance, solver) on the experiment's time grid."""
    m = experiment.model
    return Model(
        fmu_path,
        step_size_s=t.step_size_s,
        start_time_s=t.start_time_s,
        interface=m.interface,
        reset_policy=m.reset_policy,
        tolerance=m.tolerance,
        solver=m.solver,
        solver_substeps=m.solver_substeps,
        instance_name=instance_name,
        clock_intervals=m.clock_intervals,
        clock_schedule=m.clock_schedule,
    )
