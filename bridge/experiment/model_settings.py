"""The settings of one model, as the experiment's ``model:`` section and a system component share them.

One schema: :class:`ModelSettings` holds every key that describes a model instance (what
:class:`bridge.fmu.ModelSpec` carries); ``model:`` adds the experiment's own keys (sampling
time, episode, isolation, licence) and ``system.components.NAME`` its place in the system
(``feedthrough``, ``node``). So every model key valid under ``model:`` is valid under a component,
and a component given one of the experiment's own keys is told where it belongs.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from bridge.experiment.strict import FiniteFloat, PositiveFloat, Strict, invalid
from bridge.fmu.vocab import InterfaceChoice

Scalar = FiniteFloat | int | bool | str  # parameters: finite numbers only


class StateFilePolicy(Strict):
    """``reset_policy: {state_file: PATH}``: every episode starts from an FMU state saved by
    ``fmu-bridge state save`` instead of initialising (a path relative to the experiment file)."""

    state_file: str = Field(min_length=1, description="state file (relative to the experiment file)")


class ModelSettings(Strict):
    """Every setting of one model instance (the keys :class:`bridge.fmu.ModelSpec` carries)."""

    fmu: str = Field(
        default="",
        description="Path to the .fmu (relative to the experiment file) or example:NAME",
    )
    interface: InterfaceChoice = "auto"
    step_size: PositiveFloat | None = None
    parameters: dict[str, Scalar] = {}
    start_values: dict[str, Scalar] = {}
    structural_parameters: dict[str, Annotated[int, Field(ge=0, strict=True)]] = Field(
        default={},
        description="FMI 3.0 structural parameters (array sizes), set in configuration mode per instance",
    )
    reset_policy: Literal["auto", "reset", "restore", "reinstantiate"] | StateFilePolicy = "auto"
    tolerance: PositiveFloat | None = None
    solver: Literal["cvode", "rk4", "euler"] = Field(
        default="cvode",
        description="model exchange: CVode (variable step), or rk4/euler: fixed steps in native code",
    )
    solver_substeps: Annotated[int, Field(ge=1)] = Field(
        default=1, description="fixed-step solvers: integration steps per FMU step (step_size)"
    )
    clock_intervals: dict[str, PositiveFloat] = Field(
        default={}, description="FMI 3.0 fixed/tunable input clocks: the interval (s) set at initialisation"
    )
    clock_schedule: dict[str, list[FiniteFloat]] = Field(
        default={}, description="FMI 3.0 triggered input clocks: the times (s) they tick at, per episode"
    )

    @model_validator(mode="after")
    def _solver_fits(self) -> ModelSettings:
        if self.solver != "cvode" and self.interface == "cs":
            raise invalid(
                "solver",
                f"{self.solver!r} integrates model exchange, but interface is 'cs' (the FMU's own "
                "solver): set interface: me, or drop solver",
            )
        return self


#: Keys of ``model:`` that belong to the whole experiment, not to one model instance.
EXPERIMENT_KEYS = ("sampling_time", "episode_duration", "start_time", "isolation", "licence")
