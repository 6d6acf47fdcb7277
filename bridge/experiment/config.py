"""Experiment files: YAML parsed into frozen pydantic models, unknown keys rejected.

Structure checks live here; checks that need the FMU (variable names, causality, step
sizes) live in :mod:`bridge.experiment.validate`. Every error names the key, the bad value, what is
allowed, and the file.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, ValidationError, field_validator, model_validator

from bridge.errors import ConfigError
from bridge.experiment.model_settings import ModelSettings, Scalar, StateFilePolicy
from bridge.experiment.profiles import PROFILE_KINDS, Distribution, Profile
from bridge.experiment.reward import RewardSection
from bridge.experiment.safe import check_safe_name
from bridge.experiment.sections import (
    EvaluationSection,
    NodeSection,
    RecordingSection,
    RosSection,
    TrainingSection,
    check_import_path,
    check_ordered,
)
from bridge.experiment.strict import (
    FiniteFloat,
    NonNegativeFloat,
    PositiveFloat,
    Strict,
    format_validation_error,
    invalid,
)
from bridge.experiment.system import SystemSection
from bridge.experiment.yaml_text import read_yaml

__all__ = [
    "PROFILE_KINDS",
    "Distribution",
    "Experiment",
    "Profile",
    "StateFilePolicy",
    "format_validation_error",
    "load_experiment",
    "parse_experiment",
    "sampling_ratio",
]

MAX_SAMPLES = 10**7
"""Samples per episode at most: each reference and input profile is precomputed as one float64 per
sample (80 MB per signal at this limit), and an episode longer than this is almost always a
mistyped duration or sampling time (1e12 s instead of 1e2 s); run several episodes instead."""


# -- model --------------------------------------------------------------------------------------
class IsolationSection(Strict):
    """``model.isolation``: run the FMU in a child process behind a deadline (untrusted or
    unstable FMUs: a hang, a crash or a leak becomes an error instead of a dead trainer)."""

    timeout: PositiveFloat = Field(default=10.0, description="seconds a reset or one sample may take")
    memory_limit_mb: PositiveFloat | None = Field(
        default=None, description="resident memory the FMU's process may add after loading"
    )
    restart: bool = Field(default=True, description="start a fresh process at the next reset")


class LicenceSection(Strict):
    """``model.licence``: a licensed FMU runs only where, and as often as, its seats allow. On Ray each
    task or env runner asks for ``per_instance`` of the custom resource ``resource`` per FMU instance
    it opens; hosts offer seats with ``ray start --resources '{"RESOURCE": SEATS}'``, so a host runs at
    most SEATS instances at once and a host without the resource runs none."""

    resource: str = Field(min_length=1, description="Ray custom resource naming the licence's seats")
    per_instance: PositiveFloat = Field(default=1.0, description="seats one FMU instance takes")


class ModelSection(ModelSettings):
    """``model:``: the model's settings (:class:`ModelSettings`, shared with system components)
    and the experiment's own: time grid of the agent, episode, isolation, licence."""

    fmu: str = Field(
        default="",
        description="Path to the .fmu, .ssp or .ssd, or example:NAME[:FMI version][:cs|me] (bundled)",
    )
    sampling_time: PositiveFloat | None = None
    episode_duration: PositiveFloat
    start_time: FiniteFloat = 0.0
    isolation: IsolationSection | None = None
    licence: LicenceSection | None = None

    @model_validator(mode="after")
    def _samples(self) -> ModelSection:
        check_samples("episode_duration", self.episode_duration, self.sampling_time or self.step_size)
        return self


def check_samples(key: str, duration_s: float, sampling_time_s: float | None) -> None:
    """At most MAX_SAMPLES samples per episode, where the sampling time is known."""
    if sampling_time_s is None:
        return
    samples = duration_s / sampling_time_s
    if samples < 1 - 1e-9:
        raise invalid(
            key,
            f"{duration_s:g} s is shorter than one sample ({sampling_time_s:g} s): an episode needs at "
            "least one; lengthen the episode or sample more often",
        )
    if samples > MAX_SAMPLES:
        raise invalid(
            key,
            f"{duration_s:g} s at {sampling_time_s:g} s per sample is {samples:.3g} samples; "
            f"at most {MAX_SAMPLES:.0e} per episode are allowed (profiles are precomputed per sample): "
            "shorten the episode or sample less often",
        )


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
        for name in sorted(set(self.low) & set(self.high)):  # the same first error in every run
            check_ordered(f"low/high.{name}", self.low[name], self.high[name])
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
    clip: PositiveFloat | None = None

    @model_validator(mode="after")
    def _nonempty(self) -> ObservationSection:
        if not (self.outputs or self.references or self.errors):
            raise ValueError("observe at least one output, reference or error")
        if isinstance(self.scale, dict):
            for name, (low, high) in self.scale.items():
                check_ordered(f"scale.{name}", low, high)
        return self


class TerminationSection(Strict):
    """Terminal conditions (Gymnasium's ``terminated``): named signals leaving ``bounds`` and, with
    ``on_fmu_terminate``, the FMU requesting termination. Truncation is the episode duration."""

    bounds: dict[str, tuple[FiniteFloat | None, FiniteFloat | None]] = {}
    on_fmu_terminate: bool = True

    @model_validator(mode="after")
    def _ordered(self) -> TerminationSection:
        for name, (low, high) in self.bounds.items():
            check_ordered(f"bounds.{name}", low, high)
        return self


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
    episode_duration: PositiveFloat | None = None


class ScheduleSection(Strict):
    """Which scenario each episode gets: ``fixed`` (the first listed), ``round_robin``, ``random``
    or ``weighted``; ``evaluation`` names held-out scenarios for evaluation."""

    mode: Literal["fixed", "round_robin", "random", "weighted"] = "round_robin"
    training: list[str] = []
    weights: dict[str, NonNegativeFloat] = {}
    evaluation: list[str] = []


class HooksSection(Strict):
    """Python hooks given as ``module:function``: ``episode(spec, rng)`` may return a changed episode
    spec at reset; ``state(step, time_s, signals)`` may return variable values to set before a step."""

    episode: str | None = None
    state: str | None = None

    @field_validator("episode", "state")
    @classmethod
    def _import_path(cls, value: str | None) -> str | None:
        return None if value is None else check_import_path(value)


class Experiment(Strict):
    """A whole experiment file."""

    name: Annotated[str, AfterValidator(check_safe_name)] = "experiment"
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
    training: TrainingSection = TrainingSection()
    evaluation: EvaluationSection = EvaluationSection()
    node: NodeSection = NodeSection()
    ros: RosSection = RosSection()
    recording: RecordingSection = RecordingSection()
    system: SystemSection | None = None
    source: Path | None = Field(default=None, exclude=True)

    @model_validator(mode="before")
    @classmethod
    def _open_loop_reward(cls, data: Any) -> Any:
        """An open-loop experiment (no actions: a system simulated as it is) may leave out the
        reward, which is then 0; one with actions must say what it rewards."""
        if isinstance(data, dict) and "reward" not in data:
            actions = data.get("actions")
            if not (isinstance(actions, dict) and actions.get("inputs")):
                return {**data, "reward": {"terms": [{"alive": 0.0}]}}
        return data

    @model_validator(mode="after")
    def _references(self) -> Experiment:
        versions = set(self.versions) | {"v0"}
        if self.version not in versions:
            raise ValueError(f"version {self.version!r} is not defined; defined: {sorted(versions)}")
        if not self.model.fmu and self.system is None:
            raise ValueError("model.fmu: give the FMU (or an .ssp/.ssd), or a system: section")
        names = set(self.scenarios)
        for key, listed in (
            ("schedule.training", self.schedule.training),
            ("schedule.evaluation", self.schedule.evaluation),
            ("schedule.weights", list(self.schedule.weights)),
            ("evaluation.scenarios", self.evaluation.scenarios),
            ("training.eval_scenarios", self.training.eval_scenarios or []),
        ):
            missing = [n for n in listed if n not in names]
            if missing:
                raise invalid(key, f"{missing} are not scenarios; defined: {sorted(names) or 'none'}")
        residual = self.training.residual
        if residual is not None and residual.baseline not in self.evaluation.baselines:
            raise invalid(
                "training.residual.baseline",
                f"{residual.baseline!r} is not in evaluation.baselines "
                f"({sorted(self.evaluation.baselines) or 'none defined'})",
            )
        sampling_s = self.model.sampling_time or self.model.step_size
        for name, sc in self.scenarios.items():
            if sc.episode_duration is not None:
                check_samples(f"scenarios.{name}.episode_duration", sc.episode_duration, sampling_s)
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
    data = read_yaml(file)
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


def sampling_ratio(sampling_time_s: float, step_size_s: float) -> int:
    """How many FMU steps make one sample; the ratio must be a whole number."""
    ratio = sampling_time_s / step_size_s
    if not ratio <= MAX_SAMPLES:
        raise ConfigError(
            f"model.sampling_time: {sampling_time_s:g} s is {ratio:.3g} FMU steps of {step_size_s:g} s; "
            f"at most {MAX_SAMPLES:.0e} steps per sample are allowed: check both values"
        )
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
