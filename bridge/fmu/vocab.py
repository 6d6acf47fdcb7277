"""The model vocabulary: variables, model info and their JSON form, without FMPy.

What a plant serves is described in these terms wherever the model runs: read from an FMU's
modelDescription.xml in this process (``bridge.fmu.read_model_info``), or rebuilt from the JSON a
node reports (``info_from_summary``). The task, the remote plant and the deployed agent use this
module only, so none of them loads FMPy (``bridge.fmu`` loads its runtime lazily).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bridge.errors import VariableError

Interface = Literal["cs", "me"]

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

    @property
    def is_numeric(self) -> bool:
        return self.type in NUMERIC_TYPES

    @property
    def settable_at_init(self) -> bool:
        """Whether a value may be given before/at initialisation (parameter or start value)."""
        if self.variability == "constant" or self.causality in ("calculatedParameter", "independent"):
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


def unknown_variable_error(name: str, info: ModelInfo, role: str = "variable") -> VariableError:
    close = difflib.get_close_matches(name, list(info.variables), n=5, cutoff=0.5)
    hint = f"did you mean {close}?" if close else f"run `fmu-bridge inspect {info.path}` to list them"
    return VariableError(
        f"{role} {name!r} is not a variable of {info.model_name} ({len(info.variables)} variables); "
        f"{hint} [{info.path}]"
    )


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
        "problems": list(info.problems),
        "variables": [
            {
                "name": v.name,
                "causality": v.causality,
                "variability": v.variability,
                "type": v.type,
                "start": v.start,
                "min": v.min,
                "max": v.max,
                "nominal": v.nominal,
                "unit": v.unit,
                "description": v.description,
                **({"enumeration": dict(v.enum_items)} if v.enum_items else {}),
            }
            for v in info.variables.values()
        ],
    }


def info_from_summary(data: dict[str, Any]) -> ModelInfo:
    """A ModelInfo rebuilt from ``summary_of`` output (what a remote node reports about its FMU)."""
    de = data.get("default_experiment", {})
    variables = {}
    for v in data["variables"]:
        items = tuple((str(k), int(x)) for k, x in (v.get("enumeration") or {}).items())
        variables[v["name"]] = Variable(
            name=v["name"],
            value_reference=-1,
            type=v["type"],
            causality=v["causality"],
            variability=v["variability"],
            initial=None,
            start=v.get("start"),
            min=v.get("min"),
            max=v.get("max"),
            nominal=v.get("nominal"),
            unit=v.get("unit"),
            description=v.get("description"),
            enum_items=items,
        )
    return ModelInfo(
        path=Path(data.get("path", "remote.fmu")),
        fmi_version=data["fmi_version"],
        model_name=data["model_name"],
        guid=data.get("guid", ""),
        interfaces=tuple(i.lower() for i in data["interfaces"]),  # type: ignore[misc]
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
        generation_tool=data.get("generation_tool"),
        description=data.get("description"),
    )
