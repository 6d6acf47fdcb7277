"""The experiment's ``reward:`` section (also a system agent's): built-in terms, an expression, a callable.

Its own module so that ``bridge.experiment.system`` (a system agent's reward) and
``bridge.experiment.config`` (the experiment's) both import it without importing each other.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import model_validator

from bridge.experiment.sections import check_import_path
from bridge.experiment.strict import FiniteFloat, PositiveFloat, Strict, invalid, suggestion


class TrackingTerm(Strict):
    output: str
    reference: str
    norm: Literal["abs", "squared"] = "abs"
    weight: FiniteFloat = 1.0
    scale: PositiveFloat = 1.0


class SignalTerm(Strict):
    name: str
    norm: Literal["abs", "squared", "linear"] = "squared"
    weight: FiniteFloat = 1.0
    scale: PositiveFloat = 1.0


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
            unknown = [str(k) for k in data if k not in REWARD_TERMS]
            if unknown:
                hint = suggestion(unknown[0], REWARD_TERMS, "known terms")
                raise ValueError(f"unknown reward term {unknown[0]!r}; {hint}")
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
            try:
                check_import_path(self.callable)
            except ValueError as exc:
                raise invalid("callable", str(exc)) from None
        return self
