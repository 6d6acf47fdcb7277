"""Rewards from config: weighted built-in terms, a safe arithmetic expression, a Python callable.

Terms are compiled once into small closures over the task's signal vector, so a reward costs
a few microseconds per step. Penalty norms are negative (``abs``: -|x|, ``squared``: -x^2);
``linear`` is +x; every term is multiplied by its weight.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.config import RewardSection, RewardTerm
from bridge.errors import BridgeError

FloatArray = npt.NDArray[np.float64]
Term = Callable[[list[float], list[float], list[float]], float]


def reward_signal_names(section: RewardSection, known: set[str]) -> list[str]:
    """Every signal the reward reads (so the task reads it from the FMU)."""
    names: list[str] = []
    for term in section.terms:
        if term.tracking is not None:
            names += [term.tracking.output, term.tracking.reference]
        if term.signal is not None:
            names.append(term.signal.name)
    if section.expression:
        from bridge.expr import compile_expression

        names += list(
            compile_expression(section.expression, sorted(known), where="reward.expression").names_used
        )
    return names


def _norm(kind: str, weight: float, scale: float) -> Callable[[float], float]:
    if kind == "abs":
        return lambda x: -weight * abs(x) / scale
    if kind == "squared":
        return lambda x: -weight * (x / scale) ** 2
    return lambda x: weight * x / scale


def _term(term: RewardTerm, index: dict[str, int], action_inputs: Sequence[str]) -> Term:
    if term.alive is not None:
        bonus = term.alive
        return lambda s, u, p: bonus
    if term.tracking is not None:
        t = term.tracking
        o, r, f = index[t.output], index[t.reference], _norm(t.norm, t.weight, t.scale)
        return lambda s, u, p: f(s[o] - s[r])
    if term.effort is not None:
        i, f = (
            action_inputs.index(term.effort.name),
            _norm(term.effort.norm, term.effort.weight, term.effort.scale),
        )
        return lambda s, u, p: f(u[i])
    if term.rate is not None:
        i, f = action_inputs.index(term.rate.name), _norm(term.rate.norm, term.rate.weight, term.rate.scale)
        return lambda s, u, p: f(u[i] - p[i])
    assert term.signal is not None  # RewardTerm's validator admits exactly these kinds
    i, f = index[term.signal.name], _norm(term.signal.norm, term.signal.weight, term.signal.scale)
    return lambda s, u, p: f(s[i])


class Reward:
    """``reward(signals, inputs, previous_inputs, terminated) -> float``."""

    def __init__(
        self,
        terms: list[Term],
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

    def reset(self) -> None:
        """Nothing is carried between episodes today; kept for stateful rewards."""

    def __call__(
        self, signals: list[float], inputs: list[float], previous: list[float], terminated: bool
    ) -> float:
        total = 0.0
        for term in self._terms:
            total += term(signals, inputs, previous)
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


def build_reward(section: RewardSection, signal_names: Sequence[str], action_inputs: Sequence[str]) -> Reward:
    from bridge.task import load_callable

    index = {name: i for i, name in enumerate(signal_names)}
    terms = [_term(term, index, action_inputs) for term in section.terms]
    expression = None
    if section.expression:
        from bridge.expr import compile_expression

        expression = compile_expression(section.expression, list(signal_names), where="reward.expression")
    user = load_callable(section.callable, "reward.callable") if section.callable else None
    return Reward(terms, expression, user, signal_names, section.termination_penalty)
