"""The model vocabulary: variables, model info and their JSON form, without FMPy.

What a plant serves is described in these terms wherever the model runs: read from an FMU's
modelDescription.xml in this process (``bridge.fmu.read_model_info``), or rebuilt from the JSON a
node reports (``info_from_summary``). The task, the remote plant and the deployed agent use this
module only, so none of them loads FMPy (``bridge.fmu`` loads its runtime lazily).
"""

from __future__ import annotations

import difflib
import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bridge.errors import VariableError

Interface = Literal["cs", "me", "se"]
# What an experiment or a system component may ask for: an interface, or "auto" (the first the
# model offers, in this order).
InterfaceChoice = Literal["auto", "cs", "me", "se"]

NUMERIC_TYPES = frozenset(
    {
        "Float32",
        "Float64",
        "Int8",
        "UInt8",
        "Int16",
        "UInt16",
        "Int32",
        "UInt32",
        "Int64",
        "UInt64",
        "Boolean",
        "Enumeration",
    }
)


@dataclass(frozen=True)
class ClockInfo:
    """What an FMI 3.0 Clock declares: its interval variability and, where given, interval and shift."""

    interval_variability: str
    interval_s: float | None = None
    shift_s: float | None = None
    can_be_deactivated: bool = False
    priority: int = 0  # a smaller value is a higher priority (same-time ticks run in that order)


@dataclass(frozen=True)
class Variable:
    """One scalar variable of an FMU, in FMI-3 type vocabulary (``Real`` is ``Float64``)."""

    name: str
    value_reference: int
    type: str
    causality: str
    variability: str
    initial: str | None
    start: Any
    min: float | None = None
    max: float | None = None
    nominal: float | None = None
    unit: str | None = None
    description: str | None = None
    declared_type: str | None = None
    enum_items: tuple[tuple[str, int], ...] = ()
    is_array: bool = False
    dimensions: tuple[int, ...] = ()  # FMI 3.0 arrays: the size of each dimension, row-major
    dimension_vrs: tuple[int | None, ...] = ()  # per dimension: the structural parameter sizing it
    clock: ClockInfo | None = None  # FMI 3.0 Clock variables
    clocks: tuple[str, ...] = ()  # FMI 3.0 clocked variables: the clocks they belong to

    @property
    def is_numeric(self) -> bool:
        return self.type in NUMERIC_TYPES

    @property
    def size(self) -> int:
        """Number of scalar elements: 1 for a scalar, the product of the dimensions for an array."""
        return math.prod(self.dimensions) if self.dimensions else 1

    def element_starts(self) -> list[object]:
        """The start value of each scalar element, in :meth:`element_names` order (None where the
        FMU gives none). FMI 3.0 writes an array's start as space-separated values (``"1 2 3"``)
        or one value for every element; an unreadable entry is None."""
        start = self.start
        if isinstance(start, list | tuple) and len(start) == self.size:
            return list(start)
        if isinstance(start, str) and len(start.split()) == self.size:
            return [_number(x) for x in start.split()]
        return [start if isinstance(start, int | float) else None] * self.size

    def element_names(self) -> list[str]:
        """Names of the scalar elements: ``name`` for a scalar, ``name[i]``, ``name[i,j]``... for an array.

        Indices are 1-based, as Modelica tools name the elements of arrays they export as scalars
        (``a[1]``), and run in row-major order (the last index fastest), as FMI 3.0 stores arrays.
        """
        if not self.dimensions:
            return [self.name]
        ranges = (range(1, n + 1) for n in self.dimensions)
        return [f"{self.name}[{','.join(map(str, idx))}]" for idx in itertools.product(*ranges)]

    @property
    def settable_at_init(self) -> bool:
        """Whether a value may be given before/at initialisation (parameter or start value)."""
        if self.variability == "constant" or self.causality in (
            "calculatedParameter",
            "independent",
            "structuralParameter",  # set in configuration mode only (bridge.fmu.structure)
        ):
            return False
        return self.causality in ("parameter", "input") or self.initial in ("exact", "approx")

    @property
    def settable_in_step(self) -> bool:
        """Whether a value may be set between steps (inputs and tunable parameters)."""
        return self.causality == "input" or (self.causality == "parameter" and self.variability == "tunable")


@dataclass(frozen=True)
class DefaultExperiment:
    start_time_s: float | None = None
    stop_time_s: float | None = None
    step_size_s: float | None = None
    tolerance: float | None = None


@dataclass(frozen=True)
class ModelInfo:
    """Everything ``inspect`` shows, read from modelDescription.xml without loading a binary."""

    path: Path
    fmi_version: str
    model_name: str
    guid: str
    interfaces: tuple[Interface, ...]
    model_identifiers: dict[str, str]
    default_experiment: DefaultExperiment
    platforms: tuple[str, ...]
    variables: dict[str, Variable] = field(repr=False)
    can_get_set_state: dict[str, bool] = field(repr=False)
    number_of_states: int = 0
    number_of_event_indicators: int = 0
    generation_tool: str | None = None
    description: str | None = None
    problems: tuple[str, ...] = ()
    scheduled_execution: bool = False  # FMI 3.0 scheduled execution (interface "se")
    has_event_mode: bool = False  # FMI 3.0 co-simulation with event mode (clocks tick there)
    once_per_process: bool = False  # canBeInstantiatedOnlyOncePerProcess (either interface)
    needs_execution_tool: bool = False  # needsExecutionTool (either interface)
    python_backed: bool = False  # runs Python code in the process (pythonfmu, pythonfmu3 exports)
    python_requirements: tuple[str, ...] = ()  # its resources/requirements.txt, one requirement a line
    raw: Any = field(default=None, repr=False, compare=False)  # FMPy's ModelDescription, in-process only

    @property
    def fmi_major(self) -> int:
        return int(self.fmi_version.split(".")[0])

    def variable(self, name: str) -> Variable:
        """The variable called ``name``; a clear error with close matches if there is none."""
        try:
            return self.variables[name]
        except KeyError:
            raise unknown_variable_error(name, self) from None

    def by_causality(self, *causalities: str) -> list[Variable]:
        return [v for v in self.variables.values() if v.causality in causalities]

    @property
    def clocks(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.clock is not None]

    def scalar_names(self) -> list[str]:
        """Every name a config may use: scalars as declared, arrays element by element (``y[2,3]``)."""
        return [name for v in self.variables.values() for name in v.element_names()]

    def element(self, name: str) -> tuple[Variable, int | None]:
        """The variable a name refers to and, for an array element ``y[2,3]``, its row-major flat index.

        A declared name wins (FMI 1.0/2.0 exports name scalarised arrays ``a[1]``); else ``name[i,...]``
        with 1-based indices addresses an element of an FMI 3.0 array.
        """
        if name in self.variables:
            return self.variables[name], None
        match = _ELEMENT.fullmatch(name)
        var = self.variables.get(match.group(1)) if match else None
        if match is None or var is None or not var.dimensions:
            raise unknown_variable_error(name, self)
        index = tuple(int(i) for i in match.group(2).split(","))
        if len(index) != len(var.dimensions) or not all(1 <= i <= n for i, n in zip(index, var.dimensions)):
            shape = ",".join(map(str, var.dimensions))
            raise VariableError(
                f"{name!r}: index out of range for array {var.name}[{shape}] of {self.model_name}; "
                f"indices are 1-based, one per dimension, e.g. {var.element_names()[0]!r}"
            )
        flat = 0
        for i, n in zip(index, var.dimensions):
            flat = flat * n + (i - 1)
        return var, flat


_ELEMENT = re.compile(r"(.+)\[\s*(\d+(?:\s*,\s*\d+)*)\s*\]")


def _number(text: str) -> object:
    try:
        return float(text)
    except ValueError:
        return None


def unknown_variable_error(name: str, info: ModelInfo, role: str = "variable") -> VariableError:
    close = difflib.get_close_matches(name, list(info.variables), n=5, cutoff=0.5)
    hint = f"did you mean {close}?" if close else f"run `fmu-bridge inspect {info.path}` to list them"
    return VariableError(
        f"{role} {name!r} is not a variable of {info.model_name} ({len(info.variables)} variables); "
        f"{hint} [{info.path}]"
    )


def _sized_by(var: Variable, info: ModelInfo) -> list[str | None]:
    """Per dimension of an array: the structural parameter that sizes it (None for a fixed size)."""
    structural = (v for v in info.variables.values() if v.causality == "structuralParameter")
    names = {v.value_reference: v.name for v in structural}
    return [None if vr is None else names.get(vr, f"vr {vr}") for vr in var.dimension_vrs]


def summary_of(info: ModelInfo) -> dict[str, Any]:
    de = info.default_experiment
    return {
        "path": str(info.path),
        "model_name": info.model_name,
        "guid": info.guid,
        "fmi_version": info.fmi_version,
        "interfaces": [i.upper() for i in info.interfaces],
        "generation_tool": info.generation_tool,
        "description": info.description,
        "default_experiment": {
            "start_time_s": de.start_time_s,
            "stop_time_s": de.stop_time_s,
            "step_size_s": de.step_size_s,
            "tolerance": de.tolerance,
        },
        "platforms": list(info.platforms),
        "can_get_set_state": {k.upper(): v for k, v in info.can_get_set_state.items()},
        "continuous_states": info.number_of_states,
        "event_indicators": info.number_of_event_indicators,
        "scheduled_execution": info.scheduled_execution,
        "has_event_mode": info.has_event_mode,
        "once_per_process": info.once_per_process,
        "problems": list(info.problems),
        "variables": [
            {
                "name": v.name,
                "causality": v.causality,
                "variability": v.variability,
                "initial": v.initial,
                "type": v.type,
                "start": v.start,
                "min": v.min,
                "max": v.max,
                "nominal": v.nominal,
                "unit": v.unit,
                "description": v.description,
                **({"enumeration": dict(v.enum_items)} if v.enum_items else {}),
                **({"dimensions": list(v.dimensions)} if v.dimensions else {}),
                **({"sized_by": _sized_by(v, info)} if any(vr is not None for vr in v.dimension_vrs) else {}),
                **({"clock": _clock_summary(v.clock)} if v.clock is not None else {}),
            }
            for v in info.variables.values()
        ],
        "clocks": [v.name for v in info.clocks],
    }


def _clock_summary(clock: ClockInfo) -> dict[str, Any]:
    return {
        "interval_variability": clock.interval_variability,
        "interval_s": clock.interval_s,
        "shift_s": clock.shift_s,
        "can_be_deactivated": clock.can_be_deactivated,
        "priority": clock.priority,
    }


def info_from_summary(data: dict[str, Any]) -> ModelInfo:
    """A ModelInfo rebuilt from ``summary_of`` output (what a remote node reports about its FMU)."""
    de = data.get("default_experiment", {})
    variables = {}
    for v in data["variables"]:
        items = tuple((str(k), int(x)) for k, x in (v.get("enumeration") or {}).items())
        dimensions = tuple(int(n) for n in v.get("dimensions") or ())
        clock = ClockInfo(**v["clock"]) if v.get("clock") else None
        variables[v["name"]] = Variable(
            name=v["name"],
            value_reference=-1,
            type=v["type"],
            causality=v["causality"],
            variability=v["variability"],
            initial=v.get("initial"),  # decides which start values a remote env may set
            start=v.get("start"),
            min=v.get("min"),
            max=v.get("max"),
            nominal=v.get("nominal"),
            unit=v.get("unit"),
            description=v.get("description"),
            enum_items=items,
            is_array=bool(dimensions),
            dimensions=dimensions,
            clock=clock,
        )
    return ModelInfo(
        path=Path(data.get("path", "remote.fmu")),
        fmi_version=data["fmi_version"],
        model_name=data["model_name"],
        guid=data.get("guid", ""),
        interfaces=tuple(i.lower() for i in data["interfaces"]),
        model_identifiers={},
        default_experiment=DefaultExperiment(
            start_time_s=de.get("start_time_s"),
            stop_time_s=de.get("stop_time_s"),
            step_size_s=de.get("step_size_s"),
            tolerance=de.get("tolerance"),
        ),
        platforms=tuple(data.get("platforms", ())),
        variables=variables,
        can_get_set_state={k.lower(): bool(x) for k, x in data.get("can_get_set_state", {}).items()},
        number_of_states=int(data.get("continuous_states", 0)),
        number_of_event_indicators=int(data.get("event_indicators", 0)),
        scheduled_execution=bool(data.get("scheduled_execution", False)),
        has_event_mode=bool(data.get("has_event_mode", False)),
        once_per_process=bool(data.get("once_per_process", False)),
        generation_tool=data.get("generation_tool"),
        description=data.get("description"),
    )
