"""``PlantSpec``: what an FMU plant is built from, as one frozen, picklable value.

A plant serves a model: it needs the model's description (:class:`bridge.fmu.ModelSpec`: FMU,
interface, time grid, reset policy or state file, solver, structural parameters, clocks,
parameters and start values), how many FMU steps one sample is, and where it runs (in this
process, or in a child process behind a deadline). It needs no task: actions, observations,
rewards and their checks belong to the env, which checks the task once against the plant's
variables. Every FMU plant (``LocalFmuPlant``, ``IsolatedFmuPlant``, ``BatchPlant``, a system's
``FmuComponent``) and the plant factory take this value; an experiment's ``model:`` section
becomes one in :func:`bridge.plant.experiment_model.experiment_plant_spec`, a system component
in :func:`bridge.plant.system.component.component_plant_spec`.
"""

from __future__ import annotations

from dataclasses import dataclass

from bridge.errors import ConfigError
from bridge.experiment.validate import Timing
from bridge.fmu.spec import ModelSpec


@dataclass(frozen=True)
class Isolation:
    """Run the FMU in a child process (``model.isolation``): ``timeout_s`` bounds a reset or a
    sample, ``memory_limit_mb`` what the child may add after loading, ``restart`` starts a fresh
    child at the next reset after a hang or a crash."""

    timeout_s: float = 10.0
    memory_limit_mb: float | None = None
    restart: bool = True


@dataclass(frozen=True)
class PlantSpec:
    """One FMU plant: its model, its time grid, where it runs, and (a system's component) its name.

    ``timing`` says what a sample is (``steps_per_sample`` FMU steps of ``model.step_size_s``);
    ``isolation`` (None: in this process, unless the FMU needs a process of its own) where the
    FMU runs; ``component`` names the system component this plant is: its errors say so, and
    every reset sets the model's own parameters and start values under the values it is given
    (the task of a system does not know a component's settings).
    """

    model: ModelSpec
    timing: Timing
    isolation: Isolation | None = None
    component: str | None = None

    def __post_init__(self) -> None:
        m, t = self.model, self.timing
        if m.step_size_s != t.step_size_s or m.start_time_s != t.start_time_s:
            raise ConfigError(
                f"a plant's model steps {m.step_size_s} s from {m.start_time_s} s, its timing "
                f"{t.step_size_s} s from {t.start_time_s} s; give the model the timing's grid "
                f"(ModelSpec.replace(step_size_s=..., start_time_s=...))"
            )

    @property
    def label(self) -> str:
        """How errors name the plant, before saying where it runs: ``FMU cartpole.fmu``, or
        ``component 'motor' (motor.fmu`` ... for a component (closed by the plant)."""
        fmu = self.model.fmu.name
        return f"FMU {fmu}" if self.component is None else f"component {self.component!r} ({fmu}"

    def named(self, where: str) -> str:
        """The plant's name: ``FMU cartpole.fmu (in-process)``; a component ``component 'motor'
        (motor.fmu)`` in this process, ``component 'motor' (motor.fmu, child process)`` in a child."""
        if self.component is None:
            return f"{self.label} ({where})"
        return f"{self.label})" if where == "in-process" else f"{self.label}, {where})"
