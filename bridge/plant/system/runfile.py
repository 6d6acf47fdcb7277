"""A system file (``.ssp``, ``.ssd``, OSP's ``OspSystemStructure.xml``) run as it is, from the CLI.

Builds the experiment the file implies: no actions, every numeric output of every component
observed, the macro step and duration of its default experiment unless given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.plant.system.ssp import read_ssp


def ssp_experiment(
    path: Path,
    *,
    step_size_s: float | None = None,
    duration_s: float | None = None,
    system: dict[str, Any] | None = None,
) -> Experiment:
    """An experiment that runs the system of ``path`` (an .ssp/.ssd/OSP file) as it is: no actions,
    every numeric output of every component observed, the macro step and duration of its
    DefaultExperiment unless given; ``system`` is a ``system:`` section to merge (e.g. a
    component's ``feedthrough: false``, ``iteration``)."""
    from bridge.experiment.config import parse_experiment
    from bridge.fmu import read_model_info

    description = read_ssp(path)
    step = step_size_s or description.step_size_s
    if step is None:
        raise ConfigError(
            f"{path.name} gives no step size (ssd:DefaultExperiment annotation stepSize or OSP's "
            f"baseStepSize); pass --step-size SECONDS [{path}]"
        )
    outputs = [
        f"{name}.{element}"
        for name, component in description.components.items()
        for var in read_model_info(component.fmu).by_causality("output")
        if var.is_numeric
        for element in var.element_names()
    ]
    duration = duration_s or description.duration_s or step
    data: dict[str, Any] = {
        "name": path.stem,
        # absolute: model.fmu resolves against the experiment's folder, which is the file's own
        "model": {"fmu": str(path.absolute()), "step_size": step, "episode_duration": _whole(duration, step)},
        "observations": {"outputs": outputs, "scale": "none"},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    if system:
        data["system"] = system
    return parse_experiment(data, source=path)


def _whole(duration_s: float, step_s: float) -> float:
    """``duration_s`` rounded to whole macro steps (at least one)."""
    return max(1, round(duration_s / step_s)) * step_s
