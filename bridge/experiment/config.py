"""Experiment files: YAML parsed into frozen pydantic models, unknown keys rejected.

Structure checks live here; checks that need the FMU (variable names, causality, step
sizes) live in :mod:`bridge.experiment.validate`. Every error names the key, the bad value, what is
allowed, and the file.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from bridge.errors import ConfigError

Scalar = float | int | bool | str
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# -- random distributions ---------------------------------------------------------------------
class Distribution(Strict):
    """Exactly one of: ``uniform: [low, high]``, ``normal: [mean, std]``,
    ``truncnormal: [mean, std, low, high]``, ``lognormal: [median, sigma]``, ``choice: [values]``
    (with optional ``weights``)."""

    uniform: tuple[FiniteFloat, FiniteFloat] | None = None
    normal: tuple[FiniteFloat, FiniteFloat] | None = None
    truncnormal: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] | None = None
    lognormal: tuple[FiniteFloat, FiniteFloat] | None = None
    choice: list[FiniteFloat] | None = None
    weights: list[FiniteFloat] | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> Distribution:
        kinds = [k for k in ("uniform", "normal", "truncnormal", "lognormal", "choice") if getattr(self, k)]
        if len(kinds) != 1:
            raise ValueError(
                "give exactly one of uniform: [low, high], normal: [mean, std], truncnormal: "
                f"[mean, std, low, high], lognormal: [median, sigma], choice: [values]; got {kinds or 'none'}"
            )
        if self.uniform and self.uniform[0] > self.uniform[1]:
            raise ValueError(f"uniform: low must not exceed high, got {list(self.uniform)}")
        for name, std in (("normal", self.normal), ("lognormal", self.lognormal)):
            if std and std[1] < 0:
                raise ValueError(f"{name}: the spread must be >= 0, got {std[1]}")
        if self.truncnormal and not (self.truncnormal[2] < self.truncnormal[3] and self.truncnormal[1] >= 0):
            raise ValueError(f"truncnormal: need std >= 0 and low < high, got {list(self.truncnormal)}")
        if self.lognormal and self.lognormal[0] <= 0:
            raise ValueError(f"lognormal: the median must be > 0, got {self.lognormal[0]}")
        if self.weights is not None:
            if not self.choice or len(self.weights) != len(self.choice):
                raise ValueError("weights go with choice and need one weight per value")
            if min(self.weights) < 0 or sum(self.weights) <= 0:
                raise ValueError(f"weights must be >= 0 with a positive sum, got {self.weights}")
        return self

    @property
    def kind(self) -> str:
        return next(
            k for k in ("uniform", "normal", "truncnormal", "lognormal", "choice") if getattr(self, k)
        )


# -- time profiles ----------------------------------------------------------------------------
class StepSpec(Strict):
    time: FiniteFloat
    before: FiniteFloat = 0.0
    after: FiniteFloat


class RampSpec(Strict):
    start_time: FiniteFloat
    end_time: FiniteFloat
    start: FiniteFloat = 0.0
    end: FiniteFloat

    @model_validator(mode="after")
    def _ordered(self) -> RampSpec:
        if self.end_time <= self.start_time:
            raise ValueError(f"ramp: end_time ({self.end_time}) must be after start_time ({self.start_time})")
        return self


class SineSpec(Strict):
    amplitude: FiniteFloat
    frequency_hz: Annotated[float, Field(gt=0, allow_inf_nan=False)]
    phase_rad: FiniteFloat = 0.0
    offset: FiniteFloat = 0.0


class TableSpec(Strict):
    time: list[FiniteFloat]
    value: list[FiniteFloat]
    interpolation: Literal["linear", "hold"] = "linear"

    @model_validator(mode="after")
    def _table(self) -> TableSpec:
        if len(self.time) != len(self.value) or not self.time:
            raise ValueError(
                f"table: time and value need the same non-zero length, got {len(self.time)} "
                f"and {len(self.value)}"
            )
        if any(b < a for a, b in zip(self.time, self.time[1:])):
            raise ValueError("table: time must be non-decreasing")
        return self


class CsvSpec(Strict):
    file: Path
    column: str
    time_column: str = "time"
    interpolation: Literal["linear", "hold"] = "linear"


class Profile(Strict):
    """A signal over time: exactly one of constant, step, ramp, sine, table, csv.

    ``add`` sums further profiles onto it (e.g. a step plus a sine disturbance).
    """

    constant: FiniteFloat | None = None
    step: StepSpec | None = None
    ramp: RampSpec | None = None
    sine: SineSpec | None = None
    table: TableSpec | None = None
    csv: CsvSpec | None = None
    add: list[Profile] = []

    @model_validator(mode="before")
    @classmethod
    def _number_is_constant(cls, data: Any) -> Any:
        return {"constant": data} if isinstance(data, int | float) and not isinstance(data, bool) else data

    @model_validator(mode="after")
    def _one_kind(self) -> Profile:
        kinds = [k for k in PROFILE_KINDS if getattr(self, k) is not None]
        if len(kinds) != 1:
            raise ValueError(f"give exactly one of {', '.join(PROFILE_KINDS)}; got {kinds or 'none'}")
        return self


PROFILE_KINDS = ("constant", "step", "ramp", "sine", "table", "csv")


# -- model --------------------------------------------------------------------------------------
class ModelSection(Strict):
    fmu: str = Field(
        description="Path to the .fmu, or example:NAME[:FMI version][:cs|me] for a bundled model"
    )
    interface: Literal["auto", "cs", "me"] = "auto"
    step_size: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    sampling_time: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    episode_duration: Annotated[float, Field(gt=0, allow_inf_nan=False)]
    start_time: FiniteFloat = 0.0
    parameters: dict[str, Scalar] = {}
    start_values: dict[str, Scalar] = {}
    reset_policy: Literal["auto", "reset", "restore", "reinstantiate"] = "auto"
    tolerance: Annotated[float, Field(gt=0)] | None = None


# -- actions --------------------------------------------------------------------------------------
class ActionSection(Strict):
    """What the agent drives. ``continuous``: a Box in [-1, 1] scaled to ``low``/``high`` (default:
    the FMU's min/max); ``discrete``: Discrete(n) over ``levels`` of one input or a ``table`` of input
    vectors; ``multi_discrete``: MultiDiscrete over ``levels`` of each input."""

    inputs: list[str] = Field(
        default=[], description="FMU inputs or tunable parameters; none: an observation-only experiment"
    )
    type: Literal["continuous", "discrete", "multi_discrete"] = "continuous"
    low: dict[str, FiniteFloat] = {}
    high: dict[str, FiniteFloat] = {}
    levels: dict[str, list[FiniteFloat]] = {}
    table: list[list[FiniteFloat]] = []

    @model_validator(mode="after")
    def _consistent(self) -> ActionSection:
        unknown = sorted(set(self.low) | set(self.high) | set(self.levels) - set(self.inputs))
        unknown = [n for n in unknown if n not in self.inputs]
        if unknown:
            raise ValueError(f"{unknown} are not among actions.inputs {self.inputs}")
        if self.type == "discrete":
            if self.table:
                if any(len(row) != len(self.inputs) for row in self.table):
                    raise ValueError(f"each table row needs {len(self.inputs)} values (one per input)")
            elif len(self.inputs) != 1 or self.inputs[0] not in self.levels:
                raise ValueError(
                    "discrete actions need levels for their one input, or a table of input vectors"
                )
        if self.type == "multi_discrete" and set(self.levels) != set(self.inputs):
            raise ValueError(f"multi_discrete needs levels for every input {self.inputs}")
        for name, levels in self.levels.items():
            if len(levels) < 2:
                raise ValueError(f"levels of {name!r} need at least two values, got {levels}")
        return self


# -- observations -------------------------------------------------------------------------------
class ObservationSection(Strict):
    """What the agent sees: FMU ``outputs`` and scenario ``references``, scaled, optionally with
    tracking ``errors`` (reference minus output), the last action and a history of ``history`` samples."""

    outputs: list[str] = []
    references: list[str] = []
    errors: dict[str, str] = Field(default={}, description="reference name -> output it tracks")
    include_action: bool = False
    scale: Literal["auto", "none"] | dict[str, tuple[FiniteFloat, FiniteFloat]] = "auto"
    history: Annotated[int, Field(ge=1, le=1000)] = 1
    clip: FiniteFloat | None = None

    @model_validator(mode="after")
    def _nonempty(self) -> ObservationSection:
        if not (self.outputs or self.references or self.errors):
            raise ValueError("observe at least one output, reference or error")
        if isinstance(self.scale, dict):
            for name, (low, high) in self.scale.items():
                if not low < high:
                    raise ValueError(f"scale of {name!r}: need low < high, got [{low}, {high}]")
        return self


# -- reward ---------------------------------------------------------------------------------------
class TrackingTerm(Strict):
    output: str
    reference: str
    norm: Literal["abs", "squared"] = "abs"
    weight: FiniteFloat = 1.0
    scale: Annotated[float, Field(gt=0)] = 1.0


class SignalTerm(Strict):
    name: str
    norm: Literal["abs", "squared", "linear"] = "squared"
    weight: FiniteFloat = 1.0
    scale: Annotated[float, Field(gt=0)] = 1.0


class RewardTerm(Strict):
    """One of: ``alive: bonus``, ``tracking: {...}``, ``effort: {name: input, ...}``,
    ``rate: {name: input, ...}`` (change of an input between samples), ``signal: {...}``."""

    alive: FiniteFloat | None = None
    tracking: TrackingTerm | None = None
    effort: SignalTerm | None = None
    rate: SignalTerm | None = None
    signal: SignalTerm | None = None

    @model_validator(mode="before")
    @classmethod
    def _known(cls, data: Any) -> Any:
        if isinstance(data, dict):
            unknown = [k for k in data if k not in REWARD_TERMS]
            if unknown:
                raise ValueError(
                    f"unknown reward term {unknown[0]!r}; known terms: {', '.join(REWARD_TERMS)}"
                )
            if len(data) != 1:
                raise ValueError(f"each reward term has exactly one key, got {list(data)}")
        return data


REWARD_TERMS = ("alive", "tracking", "effort", "rate", "signal")


class RewardSection(Strict):
    """The reward: the sum of ``terms`` (weighted built-ins), an arithmetic ``expression`` over named
    signals, and/or a Python ``callable`` ("module:function"); ``termination_penalty`` is added on
    the sample where the episode terminates (never on truncation)."""

    terms: list[RewardTerm] = []
    expression: str | None = None
    callable: str | None = None
    termination_penalty: FiniteFloat = 0.0

    @model_validator(mode="after")
    def _something(self) -> RewardSection:
        if not (self.terms or self.expression or self.callable):
            raise ValueError("give reward terms, an expression or a callable")
        if self.callable is not None:
            _check_import_path(self.callable)
        return self


class TerminationSection(Strict):
    """Terminal conditions (Gymnasium's ``terminated``): named signals leaving ``bounds`` and, with
    ``on_fmu_terminate``, the FMU requesting termination. Truncation is the episode duration."""

    bounds: dict[str, tuple[FiniteFloat | None, FiniteFloat | None]] = {}
    on_fmu_terminate: bool = True


class VersionSection(Strict):
    """A named, immutable combination; keys left out are inherited from the top level."""

    description: str = ""
    actions: ActionSection | None = None
    observations: ObservationSection | None = None
    reward: RewardSection | None = None
    termination: TerminationSection | None = None


# -- scenarios and uncertainty ----------------------------------------------------------------------
class Randomization(Strict):
    """Per-episode draws: parameters and start values of the FMU, constant reference set-points."""

    parameters: dict[str, Distribution] = {}
    start_values: dict[str, Distribution] = {}
    references: dict[str, Distribution] = {}


class Noise(Strict):
    """Additive noise per sample: on observed outputs (sensor) and on actions (actuator, physical units)."""

    observations: dict[str, Distribution] = {}
    actions: dict[str, Distribution] = {}


class Scenario(Strict):
    description: str = ""
    parameters: dict[str, Scalar] = {}
    start_values: dict[str, Scalar] = {}
    inputs: dict[str, Profile] = Field(
        default={}, description="time profiles of FMU inputs the agent does not drive"
    )
    references: dict[str, Profile] = {}
    randomization: Randomization = Randomization()
    episode_duration: Annotated[float, Field(gt=0)] | None = None


class ScheduleSection(Strict):
    """Which scenario each episode gets: ``fixed`` (the first listed), ``round_robin``, ``random``
    or ``weighted``; ``evaluation`` names held-out scenarios for evaluation."""

    mode: Literal["fixed", "round_robin", "random", "weighted"] = "round_robin"
    training: list[str] = []
    weights: dict[str, Annotated[float, Field(ge=0)]] = {}
    evaluation: list[str] = []


class HooksSection(Strict):
    """Python hooks given as ``module:function``: ``episode(spec, rng)`` may return a changed episode
    spec at reset; ``state(step, time_s, signals)`` may return variable values to set before a step."""

    episode: str | None = None
    state: str | None = None

    @field_validator("episode", "state")
    @classmethod
    def _import_path(cls, value: str | None) -> str | None:
        if value is not None:
            _check_import_path(value)
        return value


def _check_import_path(value: str) -> None:
    module, sep, attr = value.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"expected 'module:function', got {value!r}")


class Experiment(Strict):
    """A whole experiment file."""

    name: str = "experiment"
    description: str = ""
    model: ModelSection
    actions: ActionSection = ActionSection()  # none: an observation-only experiment
    observations: ObservationSection
    reward: RewardSection
    termination: TerminationSection = TerminationSection()
    version: str = "v0"
    versions: dict[str, VersionSection] = {}
    scenarios: dict[str, Scenario] = {}
    schedule: ScheduleSection = ScheduleSection()
    randomization: Randomization = Randomization()
    noise: Noise = Noise()
    hooks: HooksSection = HooksSection()
    training: dict[str, Any] = {}
    evaluation: dict[str, Any] = {}
    node: dict[str, Any] = {}
    ros: dict[str, Any] = {}
    recording: dict[str, Any] = {}
    source: Path | None = Field(default=None, exclude=True)

    @model_validator(mode="after")
    def _references(self) -> Experiment:
        versions = set(self.versions) | {"v0"}
        if self.version not in versions:
            raise ValueError(f"version {self.version!r} is not defined; defined: {sorted(versions)}")
        names = set(self.scenarios)
        for key, listed in (
            ("schedule.training", self.schedule.training),
            ("schedule.evaluation", self.schedule.evaluation),
            ("schedule.weights", list(self.schedule.weights)),
        ):
            missing = [n for n in listed if n not in names]
            if missing:
                raise ValueError(f"{key}: {missing} are not scenarios; defined: {sorted(names) or 'none'}")
        return self

    def resolved(self, version: str | None = None) -> Experiment:
        """This experiment with ``version``'s sections in place of the top-level ones."""
        name = version or self.version
        if name == "v0" and "v0" not in self.versions:
            return self.model_copy(update={"version": "v0"})
        if name not in self.versions:
            raise ConfigError(
                f"version {name!r} is not defined in {self.source or 'the experiment'}; "
                f"defined: {sorted(set(self.versions) | {'v0'})}"
            )
        chosen = self.versions[name]
        update: dict[str, Any] = {"version": name}
        for key in ("actions", "observations", "reward", "termination"):
            if getattr(chosen, key) is not None:
                update[key] = getattr(chosen, key)
        return self.model_copy(update=update)

    @property
    def base_dir(self) -> Path:
        return self.source.parent if self.source is not None else Path.cwd()


def load_experiment(path: str | Path, *, version: str | None = None) -> Experiment:
    """Read and validate an experiment file (structure only; see ``config_check`` for FMU checks)."""
    file = Path(path)
    try:
        text = file.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read experiment file: {exc.strerror} [{file}]") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{file}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(
            f"{file}: expected a mapping of sections (model, actions, ...), got {type(data).__name__}"
        )
    return parse_experiment(data, source=file, version=version)


def parse_experiment(
    data: dict[str, Any], *, source: Path | None = None, version: str | None = None
) -> Experiment:
    """Validate an experiment given as a dict (as read from YAML)."""
    try:
        experiment = Experiment.model_validate({**data, "source": source})
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source)) from None
    return experiment.resolved(version)


def format_validation_error(exc: ValidationError, source: Path | None) -> str:
    lines = []
    for error in exc.errors():
        key = ".".join(str(part) for part in error["loc"]) or "(top level)"
        message = error["msg"].removeprefix("Value error, ")
        if error["type"] == "extra_forbidden":
            message = "unknown key (check its spelling and indentation)"
        value = error.get("input")
        shown = "" if isinstance(value, dict) else f" (got {value!r})"
        lines.append(f"  {key}: {message}{shown}")
    where = f" [{source}]" if source else ""
    return f"invalid experiment{where}:\n" + "\n".join(lines)


def sampling_ratio(sampling_time_s: float, step_size_s: float) -> int:
    """How many FMU steps make one sample; the ratio must be a whole number."""
    ratio = sampling_time_s / step_size_s
    n = round(ratio)
    if n < 1 or not math.isclose(ratio, n, rel_tol=1e-9, abs_tol=1e-9):
        raise ConfigError(
            f"model.sampling_time: {sampling_time_s} s is not a whole number of FMU steps of "
            f"{step_size_s} s (ratio {ratio:.6g}); choose a multiple, e.g. {max(n, 1) * step_size_s:g}"
        )
    return n


def known_references(experiment: Experiment) -> set[str]:
    """Reference signals the experiment's scenarios and randomisation define (not FMU variables)."""
    names = set(experiment.randomization.references)
    for sc in experiment.scenarios.values():
        names |= set(sc.references) | set(sc.randomization.references)
    return names


def scenario_inputs(experiment: Experiment) -> list[str]:
    """FMU inputs driven by scenario profiles, in first-seen order."""
    names: list[str] = []
    for sc in experiment.scenarios.values():
        names += [n for n in sc.inputs if n not in names]
    return names


def as_experiment(experiment: Experiment | str | Path, version: str | None = None) -> Experiment:
    """``experiment`` itself (resolved to ``version``), or the experiment file it names, loaded."""
    if isinstance(experiment, Experiment):
        return experiment.resolved(version) if version else experiment
    return load_experiment(experiment, version=version)
