"""Rewards from config: weighted built-in terms, a safe arithmetic expression, a Python callable.

Terms are generated once into one function over the task's signal vector
(:mod:`bridge.task.codegen`), so a reward costs a few microseconds per step. Penalty norms are
negative (``abs``: -|x|, ``squared``: -x^2); ``linear`` is +x; every term is multiplied by its
weight.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError
from bridge.experiment.reward import RewardSection
from bridge.task.codegen import Term, reward_terms

FloatArray = npt.NDArray[np.float64]


def reward_signal_names(section: RewardSection, known: set[str]) -> list[str]:
    """Every signal the reward reads (so the task reads it from the FMU)."""
    names: list[str] = []
    for term in section.terms:
        if term.tracking is not None:
            names += [term.tracking.output, term.tracking.reference]
        if term.signal is not None:
            names.append(term.signal.name)
    if section.expression:
        from bridge.task.expr import compile_expression

        names += list(
            compile_expression(section.expression, sorted(known), where="reward.expression").names_used
        )
    return names


class Reward:
    """``reward(signals, inputs, previous_inputs, terminated) -> float``."""

    def __init__(
        self,
        terms: Term | None,
        expression: Any,
        user: Callable[..., Any] | None,
        names: Sequence[str],
        penalty: float,
    ) -> None:
        self._terms = terms
        self._expression = expression
        self._user = user
        self._names = tuple(names)
        self._penalty = penalty

    @property
    def expression(self) -> Any:
        """The compiled ``reward.expression`` (``f(signals) -> float``), or None."""
        return self._expression

    @property
    def user(self) -> Callable[..., Any] | None:
        """The ``reward.callable`` (``f({name: value}) -> number``), or None."""
        return self._user

    def reset(self) -> None:
        """Nothing is carried between episodes today; kept for stateful rewards."""

    def __call__(
        self, signals: list[float], inputs: list[float], previous: list[float], terminated: bool
    ) -> float:
        total = self._terms(signals, inputs, previous) if self._terms is not None else 0.0
        if self._expression is not None:
            total += self._expression(signals)
        if self._user is not None:
            value = self._user(dict(zip(self._names, signals)))
            try:
                total += float(value)
            except (TypeError, ValueError) as exc:
                raise BridgeError(f"reward.callable returned {value!r}; expected a number") from exc
        if terminated:
            total += self._penalty
        return total


def build_reward(
    section: RewardSection,
    signal_names: Sequence[str],
    action_inputs: Sequence[str],
    user: Callable[..., Any] | None = None,
) -> Reward:
    """The reward of ``section`` over ``signal_names``; ``user`` is its ``reward.callable``, imported
    by the caller (``bridge.task.core.load_callable``)."""
    index = {name: i for i, name in enumerate(signal_names)}
    terms = reward_terms(section.terms, index, action_inputs) if section.terms else None
    expression = None
    if section.expression:
        from bridge.task.expr import compile_expression

        expression = compile_expression(section.expression, list(signal_names), where="reward.expression")
    return Reward(terms, expression, user, signal_names, section.termination_penalty)
