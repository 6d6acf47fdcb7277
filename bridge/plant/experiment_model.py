"""The experiment's FMU as a ``Model``: one place that maps the ``model`` section to its settings."""

from __future__ import annotations

from pathlib import Path

from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, resolve_state_file
from bridge.fmu import Model, state_file


def experiment_model(
    experiment: Experiment,
    fmu_path: Path,
    t: Timing,
    instance_name: str | None = None,
    *,
    from_state_file: bool = True,
) -> Model:
    """An instance of the experiment's FMU with its ``model`` section's settings (interface, reset
    policy, tolerance, solver, structural parameters) on the experiment's time grid; with
    ``reset_policy: {state_file: ...}`` every episode starts from that saved state (unless
    ``from_state_file`` is False)."""
    m = experiment.model
    saved = resolve_state_file(experiment) if from_state_file else None
    model = Model(
        fmu_path,
        step_size_s=t.step_size_s,
        start_time_s=t.start_time_s,
        interface=m.interface,
        reset_policy=m.reset_policy if isinstance(m.reset_policy, str) else "restore",
        tolerance=m.tolerance,
        solver=m.solver,
        solver_substeps=m.solver_substeps,
        instance_name=instance_name,
        structural_parameters=m.structural_parameters or None,
        clock_intervals=m.clock_intervals,
        clock_schedule=m.clock_schedule,
    )
    if saved is not None:
        try:
            model.start_from(state_file.read(saved), str(saved))
        except BaseException:
            model.close()
            raise
    return model
