"""The sections of an experiment file read by the tools around the env: training, evaluation,
recording, node and ros. Each is a frozen model whose unknown keys are errors with close matches.

Only ``training.hyperparams`` is free-form: its keys go to the stable-baselines3 algorithm as they
are (``policy_kwargs``, schedules such as ``lin_0.001``), and SB3 names the ones it does not take.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator

from bridge.experiment.control import ControlDesign
from bridge.experiment.safe import check_own_module
from bridge.experiment.strict import FiniteFloat, PositiveFloat, Strict, invalid

Count = Annotated[int, Field(ge=1, le=10**12)]


def check_import_path(value: str) -> str:
    """``module:function``, or a ValueError saying what was expected."""
    module, sep, attr = value.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"expected 'module:function', got {ascii(value)[:80]}")
    check_own_module(module)
    if not all(part.isidentifier() for part in attr.split(".")):
        raise ValueError(f"{ascii(attr)[:60]} is not a function name (expected 'module:function')")
    return value


def check_ordered(key: str, low: float | None, high: float | None) -> None:
    """``low < high`` where both are given; reversed bounds would make every sample out of range."""
    if low is not None and high is not None and not low < high:
        raise invalid(key, f"need [low, high] with low < high, got [{low}, {high}]")


# -- training -------------------------------------------------------------------------------------
REPLACE_WAIT_S = 30.0  # how long a vector env waits for a dead node's replacement, by default


class RemoteSection(Strict):
    """``training.remote``: the FMU nodes a ``vec: remote`` run trains on."""

    nodes: str = "*"
    connect: list[str] = []
    listen: list[str] = []
    zenoh_config: str | None = None
    zenoh_mode: Literal["client", "peer"] | None = None
    timeout_s: PositiveFloat = 5.0
    replace_dead: bool = False
    replace_wait_s: Annotated[float, Field(ge=0, le=3600, allow_inf_nan=False)] = REPLACE_WAIT_S


class NormalizeSection(Strict):
    """``training.normalize`` as a mapping: stable-baselines3's VecNormalize settings."""

    training: bool = True
    norm_obs: bool = True
    norm_reward: bool = True
    clip_obs: PositiveFloat = 10.0
    clip_reward: PositiveFloat = 10.0
    gamma: Annotated[float, Field(gt=0, le=1)] = 0.99
    epsilon: PositiveFloat = 1e-8


class ResidualSection(Strict):
    """``training.residual``: the agent's action times ``scale`` (physical units) is added to
    the output of ``baseline``, one of ``evaluation.baselines``."""

    baseline: str
    scale: PositiveFloat = 1.0


class TrainingSection(Strict):
    """``training:`` (RL Zoo-like); every key may be overridden on the command line."""

    algo: Literal["PPO", "SAC", "TD3", "A2C", "DQN"] = "PPO"
    timesteps: Count = 100_000
    n_envs: Annotated[int, Field(ge=1, le=4096)] = 4
    vec: Literal["dummy", "subproc", "remote", "batch"] = "dummy"
    seed: Annotated[int, Field(ge=0, lt=2**32)] = 0
    hyperparams: dict[str, Any] = Field(default={}, description="passed to the SB3 algorithm as is")
    normalize: bool | NormalizeSection = False
    checkpoint_every: Count | None = Field(
        default=None, description="steps between checkpoints; default: a tenth of the run, at most 50,000"
    )
    eval_every: Count = 10_000
    eval_episodes: Annotated[int, Field(ge=1, le=10**6)] = 5
    eval_scenarios: list[str] | None = None
    residual: ResidualSection | None = None
    remote: RemoteSection = RemoteSection()
    sample_timeout_s: PositiveFloat | None = Field(
        default=None,
        description="train --engine rllib: seconds an env runner may take for one sample (RLlib's "
        "sample_timeout_s; late samples are dropped); unset: as long as the plant takes",
    )

    @property
    def checkpoint_steps(self) -> int:
        """Steps between checkpoints: ``checkpoint_every``, else a tenth of ``timesteps`` (at most
        50,000), so that a short run can be resumed too."""
        if self.checkpoint_every is not None:
            return self.checkpoint_every
        return max(1, min(50_000, self.timesteps // 10))


# -- evaluation -----------------------------------------------------------------------------------
PID_KEYS: tuple[str, ...] = ("output", "reference", "input", "kp", "ki", "kd", "limits", "anti_windup")
PID_KEYS += ("tracking_time_s", "feedforward", "feedforward_gains")
BASELINE_KEYS = {"pid": PID_KEYS, "constant": ("value",), "python": ("callable",)}
BASELINE_KEYS |= {"lqr": ("design",), "mpc": ("design",)}


class BaselineSection(Strict):
    """One of ``evaluation.baselines``: ``type: pid`` (the default; output, reference, input, gains,
    ``limits``, ``anti_windup``, a constant ``feedforward`` and ``feedforward_gains`` on signals),
    ``type: constant`` (``value`` in physical units) or ``type: python`` (``callable:
    module:function``), or ``type: lqr`` / ``type: mpc`` (a ``design`` from the linearised FMU,
    ``bridge.experiment.control``)."""

    type: Literal["pid", "constant", "python", "lqr", "mpc"] = "pid"
    output: str | None = None
    reference: str | None = None
    input: str | None = None
    kp: FiniteFloat = 1.0
    ki: FiniteFloat = 0.0
    kd: FiniteFloat = 0.0
    limits: tuple[FiniteFloat, FiniteFloat] | None = None
    anti_windup: Literal["clamp", "back_calculation", "none"] = "clamp"
    tracking_time_s: PositiveFloat | None = None
    feedforward: FiniteFloat = 0.0
    feedforward_gains: dict[str, FiniteFloat] = Field(
        default={}, description="signal name -> gain: u += gain * signal (e.g. curvature feed-forward)"
    )
    value: FiniteFloat | None = None
    callable: str | None = None
    design: ControlDesign | None = None

    @model_validator(mode="after")
    def _fits_type(self) -> BaselineSection:
        allowed = {"type", *BASELINE_KEYS[self.type]}
        foreign = sorted(self.model_fields_set - allowed)
        if foreign:
            raise ValueError(f"{foreign} do not apply to a {self.type} baseline; it takes {sorted(allowed)}")
        required = {"pid": PID_KEYS[:3], "constant": ("value",), "python": ("callable",)}
        required |= {"lqr": ("design",), "mpc": ("design",)}
        missing = [k for k in required[self.type] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"a {self.type} baseline needs {missing}")
        if self.limits is not None:
            check_ordered("limits", *self.limits)
        if self.callable is not None:
            try:
                check_import_path(self.callable)
            except ValueError as exc:
                raise invalid("callable", str(exc)) from None
        return self

    def settings(self) -> dict[str, Any]:
        """The keys given in the file (the agents' policies apply their own defaults)."""
        return self.model_dump(exclude_unset=True)


class MetricsSection(Strict):
    """``evaluation.metrics``: which metrics each episode gets besides return and length."""

    tracking: list[tuple[str, str]] = Field(default=[], description="[output, reference] pairs")
    effort: list[str] | None = Field(default=None, description="action inputs; default: all")
    constraints: dict[str, tuple[FiniteFloat | None, FiniteFloat | None]] = {}
    success: str | None = Field(default=None, description="an expression over metric names")
    user: list[str] = Field(default=[], description="module:function of the episode trace")
    settling_band: Annotated[float, Field(gt=0, lt=1)] = 0.02

    @field_validator("user")
    @classmethod
    def _import_paths(cls, value: list[str]) -> list[str]:
        return [check_import_path(v) for v in value]

    @model_validator(mode="after")
    def _ordered(self) -> MetricsSection:
        for name, (low, high) in self.constraints.items():
            check_ordered(f"constraints.{name}", low, high)
        return self


class EvaluationSection(Strict):
    """``evaluation:``: episodes per scenario, held-out scenarios, baselines and metrics."""

    episodes: Annotated[int, Field(ge=1, le=10**6)] = 5
    scenarios: list[str] = []
    baselines: dict[str, BaselineSection] = {}
    metrics: MetricsSection = MetricsSection()
    plots: list[str] = Field(default=[], description="signals the report plots (default: all)")
    baseline_signals: Literal["measured", "exact"] = Field(
        default="measured",
        description="what baselines read: the agent's sensors (noise included) or the exact model values",
    )


# -- recording, node, ROS -------------------------------------------------------------------------
class RecordingSection(Strict):
    """``recording:``: where ``fmu-bridge simulate`` records and how its MCAP files are written."""

    directory: Path = Field(default=Path("recordings"), description="relative to the working directory")
    compression: Literal["zstd", "none"] = "zstd"
    chunk_size: Annotated[int, Field(ge=1024, le=64 << 20, description="uncompressed bytes per chunk")] = (
        128 * 1024
    )


class NodeSection(Strict):
    """``node:``: defaults of ``fmu-bridge node`` (each overridden by its command-line option)."""

    name: Annotated[str, Field(min_length=1)] = "fmu"
    mode: Literal["lockstep", "realtime"] = "lockstep"
    rate: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 1.0
    prefix: Annotated[str, Field(min_length=1)] = "fmu_bridge"
    network: bool = Field(default=False, description="serve on every interface with scouting (--network)")


class RosSection(Strict):
    """``ros:``: the ROS 2 view of a node (all optional; see docs/ros2.md)."""

    domain_id: Annotated[int, Field(ge=0, le=232)] | None = None
    namespace: str = "/"
    node_name: str | None = None
    outputs_topic: str = "~/outputs"
    actions_topic: str = "~/actions"
    reset_service: str = "~/reset"
    clock: bool = True
    per_variable: bool = False
    reliability: Literal["reliable", "best_effort"] = "reliable"
    depth: Annotated[int, Field(ge=1, le=10_000)] = 10
    backend: Literal["zenoh", "rclpy"] = "zenoh"
    follow_clock: bool = False  # step on an external /clock (use_sim_time); see docs/ros2.md
    reset_keeps_inputs: bool = False  # ~/reset keeps the held inputs (default: back to their start values)
