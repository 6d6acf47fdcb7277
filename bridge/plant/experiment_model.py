"""The experiment's FMU as a description: the one place that maps the ``model`` section to a
:class:`bridge.fmu.ModelSpec` (:func:`experiment_spec`) and to the :class:`PlantSpec` its plant is
built from (:func:`experiment_plant_spec`); :func:`experiment_model` opens the model itself."""

from __future__ import annotations

from pathlib import Path

from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, configured, resolve_fmu, resolve_state_file, timing
from bridge.fmu import Model, read_model_info
from bridge.fmu.opening import open_model
from bridge.fmu.spec import ModelSpec
from bridge.fmu.vocab import ModelInfo
from bridge.plant.spec import Isolation, PlantSpec


def experiment_spec(
    experiment: Experiment,
    fmu_path: Path,
    t: Timing,
    instance_name: str | None = None,
    *,
    from_state_file: bool = True,
) -> ModelSpec:
    """The model the ``model`` section describes, on the experiment's time grid; with
    ``reset_policy: {state_file: ...}`` every episode starts from that saved state (unless
    ``from_state_file`` is False)."""
    m = experiment.model
    saved = resolve_state_file(experiment) if from_state_file else None
    return ModelSpec.of(
        fmu_path,
        step_size_s=t.step_size_s,
        start_time_s=t.start_time_s,
        interface=m.interface,
        reset_policy=m.reset_policy if isinstance(m.reset_policy, str) else "restore",
        state_file=saved,
        tolerance=m.tolerance,
        solver=m.solver,
        solver_substeps=m.solver_substeps,
        instance_name=instance_name,
        structural_parameters=m.structural_parameters,
        clock_intervals=m.clock_intervals,
        clock_schedule=m.clock_schedule,
        parameters=m.parameters,
        start_values=m.start_values,
    )


def experiment_plant_spec(experiment: Experiment, info: ModelInfo | None = None) -> PlantSpec:
    """The plant the experiment's ``model`` section describes: its model (:func:`experiment_spec`),
    the agent's time grid (``step_size``, ``sampling_time``; the FMU's default step where the file
    gives none) and ``model.isolation``. ``info``: the FMU's model, where the caller has read it.

    Checks the time grid, not the task: the env checks the task against the plant's variables."""
    fmu = resolve_fmu(experiment)
    info = configured(experiment, info if info is not None else read_model_info(fmu))
    t = timing(experiment, info)
    section = experiment.model.isolation
    isolation = None
    if section is not None:
        isolation = Isolation(section.timeout, section.memory_limit_mb, section.restart)
    return PlantSpec(experiment_spec(experiment, fmu, t), t, isolation)


def experiment_model(
    experiment: Experiment,
    fmu_path: Path,
    t: Timing,
    instance_name: str | None = None,
    *,
    from_state_file: bool = True,
) -> Model:
    """An instance of the experiment's FMU (:func:`experiment_spec`, opened by :func:`open_model`)."""
    spec = experiment_spec(experiment, fmu_path, t, instance_name, from_state_file=from_state_file)
    return open_model(spec)
