"""``ModelSpec``: every setting of one model instance, as one frozen, picklable value.

The experiment's ``model:`` section, a system component (``system.components.NAME``, the same
keys) and the Python API describe a model the same way: FMU, interface, time grid, reset policy
(or a state file every episode starts from), tolerance, solver and substeps, structural
parameters, clock intervals and schedule, parameters and start values (FMI 3.0 array elements
by the element names actions use, ``A[1,2]``). ``open_model`` (:mod:`bridge.fmu.opening`) is the
one function that turns a description into a :class:`bridge.fmu.Model`; every plant opens its FMU
through it, so a setting added here reaches every path at once. Importing this module loads no
FMPy.

Example:
    >>> from bridge.fmu import open_model
    >>> spec = ModelSpec.of("cartpole.fmu", step_size_s=0.02, parameters={"m": 1.2})
    >>> with open_model(spec) as model:
    ...     model.initialize(spec.initial_values())
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

InterfaceChoice = Literal["auto", "cs", "me", "se"]  # auto: co-simulation where the FMU has it
ResetPolicy = Literal["auto", "reset", "restore", "reinstantiate"]
Solver = Literal["cvode", "rk4", "euler"]
Pairs = tuple[tuple[str, Any], ...]


@dataclass(frozen=True)
class ModelSpec:
    """One model instance's settings. Mappings are held as tuples of ``(name, value)`` pairs so
    that the value is hashable and cannot change; :meth:`of` takes them as mappings.

    ``step_size_s`` and ``start_time_s`` default to the FMU's default experiment;
    ``state_file`` makes every episode start from that saved state (``bridge.fmu.state_file``).
    """

    fmu: Path
    interface: InterfaceChoice = "auto"
    step_size_s: float | None = None
    start_time_s: float | None = None
    stop_time_s: float | None = None
    reset_policy: ResetPolicy = "auto"
    state_file: Path | None = None
    tolerance: float | None = None
    solver: Solver = "cvode"
    solver_substeps: int = 1
    structural_parameters: Pairs = ()
    clock_intervals: Pairs = ()
    clock_schedule: Pairs = ()
    parameters: Pairs = ()
    start_values: Pairs = ()
    instance_name: str | None = None

    @classmethod
    def of(
        cls,
        fmu: str | Path,
        *,
        structural_parameters: Mapping[str, int] | None = None,
        clock_intervals: Mapping[str, float] | None = None,
        clock_schedule: Mapping[str, Sequence[float]] | None = None,
        parameters: Mapping[str, Any] | None = None,
        start_values: Mapping[str, Any] | None = None,
        state_file: str | Path | None = None,
        **settings: Any,
    ) -> ModelSpec:
        """A description from mappings (the form configs and callers hold them in)."""
        schedule = {k: tuple(float(t) for t in v) for k, v in (clock_schedule or {}).items()}
        return cls(
            Path(fmu),
            structural_parameters=_pairs(structural_parameters),
            clock_intervals=_pairs(clock_intervals),
            clock_schedule=_pairs(schedule),
            parameters=_pairs(parameters),
            start_values=_pairs(start_values),
            state_file=Path(state_file) if state_file is not None else None,
            **settings,
        )

    def initial_values(self) -> dict[str, Any]:
        """Parameters and start values, by name, for every initialisation (scenario values go over them)."""
        return {**dict(self.parameters), **dict(self.start_values)}

    def replace(self, **changes: Any) -> ModelSpec:
        """A copy with ``changes`` (field names as in the class)."""
        return replace(self, **changes)


def _pairs(values: Mapping[str, Any] | None) -> Pairs:
    return tuple((str(k), v) for k, v in (values or {}).items())
