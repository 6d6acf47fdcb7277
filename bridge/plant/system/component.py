"""``FmuComponent``: one FMU of a system in this process, a plant stepping one macro step a sample.

A :class:`bridge.plant.local.LocalFmuPlant` built from a component's description
(:func:`component_plant_spec`): a macro step of ``H`` is ``n`` FMU steps of the component's own
step size ``h`` (multi-rate, inputs held); every reset sets the component's own parameters and
start values under what the system's task gives. What it adds is what the system's master
asks of an in-process component (native stepping accounts, settling direct feedthrough).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from bridge.errors import ConfigError
from bridge.experiment.validate import Timing
from bridge.fmu.sample import sample_failure
from bridge.fmu.spec import ModelSpec
from bridge.plant.base import FloatArray
from bridge.plant.local import LocalFmuPlant
from bridge.plant.spec import PlantSpec
from bridge.plant.system.description import Component


def steps_per_macro(component: Component, macro_step_s: float, default_s: float | None, where: str) -> int:
    """How many steps of the component's own size make one macro step (must be whole)."""
    h = component.step_size_s or default_s or macro_step_s
    if h > macro_step_s * (1 + 1e-9):
        raise ConfigError(
            f"system.components.{component.name}.step_size: {h:g} s is longer than the macro step "
            f"{macro_step_s:g} s; a component steps whole steps inside each macro step, so the macro "
            f"step must be its step or a multiple of it (e.g. {h:g}){where}"
        )
    ratio = macro_step_s / h
    n = round(ratio)
    if n < 1 or not math.isclose(ratio, n, rel_tol=1e-9):
        raise ConfigError(
            f"system.components.{component.name}.step_size: {h} s does not divide the macro step "
            f"{macro_step_s} s (ratio {ratio:.6g}); choose {macro_step_s}/k{where}"
        )
    return n


def component_spec(component: Component, step_size_s: float, start_time_s: float) -> ModelSpec:
    """The model a component describes, on its own time grid (``step_size_s`` divides the macro step)."""
    return ModelSpec.of(
        component.fmu,
        step_size_s=step_size_s,
        start_time_s=start_time_s,
        interface=component.interface,
        instance_name=component.name,
        reset_policy=component.reset_policy if component.state_file is None else "restore",
        state_file=component.state_file,
        tolerance=component.tolerance,
        solver=component.solver,
        solver_substeps=component.solver_substeps,
        structural_parameters=component.structural_parameters,
        clock_intervals=component.clock_intervals,
        clock_schedule=component.clock_schedule,
        parameters=component.parameters,
        start_values=component.start_values,
    )


def component_plant_spec(
    component: Component, macro_step_s: float, start_time_s: float, where: str = ""
) -> PlantSpec:
    """The plant a component describes: a sample is one macro step of ``n`` steps of its own size."""
    n = steps_per_macro(component, macro_step_s, None, where)  # default: one step per macro step
    t = Timing(macro_step_s / n, n, macro_step_s, start_time_s)
    return PlantSpec(component_spec(component, t.step_size_s, start_time_s), t, component=component.name)


class FmuComponent(LocalFmuPlant):
    """One component's FMU in this process (:func:`component_plant_spec`); a sample is one macro step."""

    def native_done(self) -> None:
        """Account a sample the native master stepped (:mod:`.native_master`)."""
        self.terminated = self.model.terminated
        self.sample += 1

    def native_failed(self, status: int) -> None:
        """Raise the error of a sample the native master stepped and the FMU failed (as :meth:`step`)."""
        raise self._failed(sample_failure(self.model, status, self.input_names, self.output_names))

    can_settle = True

    def settle(self, inputs: Sequence[float]) -> FloatArray:
        """Set the inputs at the current communication point and read the outputs again, without
        a step: direct feedthrough outputs then follow the inputs of this instant."""
        self._write(inputs)
        outputs: FloatArray = self._read()
        return outputs
