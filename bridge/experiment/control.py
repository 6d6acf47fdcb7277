"""``design:`` of an ``lqr`` or ``mpc`` baseline: the model-based controllers of ``bridge.control``.

Names are the FMU's: ``states`` are its continuous states, ``inputs`` the action inputs the
controller drives, ``disturbances`` further FMU inputs whose current value a task signal gives
(their future values come from ``preview`` signals), ``tracking`` maps FMU outputs to the task
reference each should follow. Weights are diagonal, per name, in the variables' own units.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from bridge.experiment.strict import FiniteFloat, NonNegativeFloat, PositiveFloat, Strict


class ScheduleSpec(Strict):
    """Gain scheduling: one design per value of an FMU input, interpolated on a task signal."""

    input: str = Field(description="the FMU input set to each point when linearising (e.g. v_x)")
    signal: str = Field(description="the task signal that selects the design at run time (e.g. speed)")
    points: list[FiniteFloat] = Field(min_length=1, description="values of the input, increasing")

    @model_validator(mode="after")
    def _increasing(self) -> ScheduleSpec:
        if any(b <= a for a, b in zip(self.points, self.points[1:])):
            raise ValueError(f"schedule.points must increase strictly, got {self.points}")
        return self


class ControlDesign(Strict):
    """How an LQR or MPC baseline is designed from the linearised FMU."""

    inputs: list[str] = Field(min_length=1, description="action inputs the controller drives")
    states: list[str] | None = Field(default=None, description="FMU continuous states; default all")
    measured: list[str] = Field(min_length=1, description="task signals (FMU outputs) the estimator uses")
    q: dict[str, NonNegativeFloat] = Field(default={}, description="state (or tracked output) weights")
    r: dict[str, PositiveFloat] = Field(default={}, description="input weights; default 1")
    tracking: dict[str, str] = Field(default={}, description="FMU output -> task reference signal")
    integral: dict[str, NonNegativeFloat] = Field(
        default={}, description="tracked output -> weight on the integral of its error"
    )
    disturbances: dict[str, str] = Field(default={}, description="FMU input -> task signal (its value now)")
    preview: dict[str, dict[PositiveFloat, str]] = Field(
        default={}, description="FMU input -> {seconds ahead: task signal}"
    )
    operating_point: dict[str, FiniteFloat] = Field(
        default={}, description="states, inputs and parameters at the linearisation point"
    )
    schedule: ScheduleSpec | None = None
    measurement_noise: dict[str, PositiveFloat] = Field(
        default={}, description="standard deviation per measured signal; default the experiment's noise"
    )
    process_noise: PositiveFloat = Field(
        default=0.01, description="process noise standard deviation per state, relative to its nominal"
    )
    horizon: Annotated[int, Field(ge=1, le=500)] = 20
    rate_limits: dict[str, PositiveFloat] = Field(
        default={},
        description="|du/dt| per input, physical units per second: the mpc's constraint, the lqr's "
        "command limiter (both keep the command within what the actuator can follow)",
    )
    limits: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(
        default={}, description="input limits; default the action space's"
    )
    output_limits: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(
        default={},
        description="mpc: FMU outputs kept within [low, high] over the horizon (soft: a slack with a heavy "
        "penalty keeps the QP feasible), e.g. the lateral acceleration the grip allows",
    )

    @model_validator(mode="after")
    def _consistent(self) -> ControlDesign:
        stray = sorted(set(self.integral) - set(self.tracking))
        if stray:
            raise ValueError(
                f"integral {stray} must be tracked outputs too (tracking: {sorted(self.tracking)})"
            )
        stray = sorted(set(self.preview) - set(self.disturbances))
        if stray:
            raise ValueError(
                f"preview {stray} must be disturbances too (disturbances: {sorted(self.disturbances)})"
            )
        for key, table in (("limits", self.limits), ("output_limits", self.output_limits)):
            for name, (low, high) in table.items():
                if not low < high:
                    raise ValueError(f"{key}.{name}: low {low} must be below high {high}")
        stray = sorted(set(self.rate_limits) - set(self.inputs))
        if stray:
            raise ValueError(f"rate_limits {stray} must be inputs too (inputs: {self.inputs})")
        return self
