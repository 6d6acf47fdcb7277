"""The parts of a system as data: components (FMUs), connections, units and the system itself.

Plain frozen data, so that every reader of a system (the YAML ``system:`` section in
:mod:`bridge.plant.system.description`, SSP in :mod:`bridge.plant.system.ssp`, OSP in
:mod:`bridge.plant.system.osp`) builds the same :class:`SystemDescription` without importing
another reader.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bridge.fmu.vocab import InterfaceChoice

Algorithm = Literal["jacobi", "gauss_seidel"]


@dataclass(frozen=True)
class Endpoint:
    """``component.variable``; the variable name may itself contain dots (Modelica names)."""

    component: str
    variable: str

    def __str__(self) -> str:
        return f"{self.component}.{self.variable}"


@dataclass(frozen=True)
class Transform:
    """An SSP connection transformation (``ssc:<kind>``): ``LinearTransformation`` computes
    ``factor * value + offset``; the three mapping kinds replace a value by its ``MapEntry``
    target (``entries``: source and target as written, enumerations by item name)."""

    kind: Literal[
        "LinearTransformation",
        "BooleanMappingTransformation",
        "IntegerMappingTransformation",
        "EnumerationMappingTransformation",
    ]
    factor: float = 1.0
    offset: float = 0.0
    entries: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Unit:
    """A unit as SSP and FMI define one: ``value_SI = factor * value + offset`` in the SI base
    units whose exponents ``base`` gives (kg, m, s, A, K, mol, cd, rad)."""

    name: str
    base: tuple[int, ...]
    factor: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class Connection:
    """An output of one component feeding an input of another, held over each macro step;
    from an SSP, with the connection's transformation and whether it suppresses unit conversion."""

    source: Endpoint
    target: Endpoint
    transform: Transform | None = None
    suppress_units: bool = False

    def __str__(self) -> str:
        return f"{self.source} -> {self.target}"


@dataclass(frozen=True)
class Component:
    """One FMU of the system; ``step_size_s`` None means one FMU step per macro step."""

    name: str
    fmu: Path
    parameters: dict[str, Any] = field(default_factory=dict)
    step_size_s: float | None = None
    interface: InterfaceChoice = "auto"
    feedthrough: bool | None = None
    node: str | None = None
    connector_units: dict[str, str] = field(default_factory=dict)  # from an SSD's connectors
    structural_parameters: dict[str, int] = field(default_factory=dict)  # FMI 3.0 array sizes
    clock_intervals: dict[str, float] = field(default_factory=dict)  # FMI 3.0 clocks (docs/clocks.md)
    clock_schedule: dict[str, list[float]] = field(default_factory=dict)
    # the rest of a model's settings, as under model: (bridge.experiment.model_settings)
    start_values: dict[str, Any] = field(default_factory=dict)
    reset_policy: Literal["auto", "reset", "restore", "reinstantiate"] = "auto"
    state_file: Path | None = None  # every episode from this saved state (resolved path)
    tolerance: float | None = None
    solver: Literal["cvode", "rk4", "euler"] = "cvode"
    solver_substeps: int = 1


@dataclass(frozen=True)
class SystemDescription:
    """Components in declaration order, connections, and how to step them."""

    components: dict[str, Component]
    connections: tuple[Connection, ...]
    algorithm: Algorithm = "jacobi"
    max_iterations: int = 1
    tolerance: float = 1e-10
    order: tuple[str, ...] = ()
    feedthrough_outputs: Literal["held", "updated"] = "held"
    step_size_s: float | None = None  # an SSP's default experiment step, if it gives one
    source: Path | None = None
    units: dict[str, Unit] = field(default_factory=dict)  # an SSD's unit definitions by name
    ssp: Path | None = None  # the .ssp/.ssd the components and connections came from, if any
    duration_s: float | None = None  # an SSP's stopTime - startTime, if it gives one
    start_time_s: float | None = None  # an SSP's startTime or OSP's StartTime, if it gives one
    warnings: tuple[str, ...] = ()  # what the file asked for and was mapped with a change

    @property
    def where(self) -> str:
        return f" [{self.source}]" if self.source else ""
