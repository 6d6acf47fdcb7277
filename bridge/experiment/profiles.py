"""Random distributions and time profiles: the values scenarios draw and the signals they drive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from bridge.experiment.strict import FiniteFloat, Strict

# -- random distributions ---------------------------------------------------------------------
MAX_DRAW_MAGNITUDE = 1e100
"""Largest magnitude of a distribution's parameters: finite floats near 1e308 overflow to infinity
in ``high - low`` or ``mean + k * std``, so such a draw would be infinite or NaN."""


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
        if self.lognormal and self.lognormal[1] > 20:
            raise ValueError(f"lognormal: sigma must be at most 20, got {self.lognormal[1]}")
        self._check_magnitudes()
        if self.weights is not None:
            if not self.choice or len(self.weights) != len(self.choice):
                raise ValueError("weights go with choice and need one weight per value")
            if min(self.weights) < 0 or sum(self.weights) <= 0:
                raise ValueError(f"weights must be >= 0 with a positive sum, got {self.weights}")
        return self

    def _check_magnitudes(self) -> None:
        kind = self.kind
        values = [float(v) for v in getattr(self, kind)]
        large = [v for v in values if abs(v) > MAX_DRAW_MAGNITUDE]
        if large:
            raise ValueError(
                f"{kind}: {large} beyond +-{MAX_DRAW_MAGNITUDE:g}; draws that wide overflow to "
                "infinity: give the range the model can take"
            )

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
