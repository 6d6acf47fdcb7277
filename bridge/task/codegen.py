"""The Task's generated functions: every source the task generates, and the one place it is compiled.

Reward terms, observation elements and the termination check are generated once per task as a
single Python expression each, from indices and floats taken from the validated config (names
and user text never enter a source), so these are code templates, not evaluation of user input;
one expression costs a fraction of a chain of closures or numpy calls for a handful of values.

The same reward and observation sources run per env on lists of floats (:class:`~bridge.task.core.Task`)
and over whole batches on numpy columns (:class:`~bridge.task.batch.BatchTask`). So that both
are the same arithmetic on every CPU, a source uses only operations that IEEE 754 rounds
exactly and that numpy evaluates elementwise with the same result whatever SIMD it dispatches
to: ``+ - * /``, ``abs``, ``min``/``max`` and comparisons. A square is written ``q * q`` (with
``q`` named once by an assignment expression), never ``q ** 2``: numpy's vectorised ``power`` and
the C library's ``pow`` differ in the last bit for some values and CPUs (AVX-512 among them).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from bridge.experiment.reward import RewardTerm

Term = Callable[[list[float], list[float], list[float]], float]
Observe = Callable[[list[float], list[float], list[float]], list[float]]
Terminate = Callable[[list[float]], "str | None"]

# What a source may call, per evaluation: plain floats, or numpy columns of a batch.
_SCALAR: dict[str, Any] = {"__builtins__": {}, "abs": abs, "min": min, "max": max}
_BATCH: dict[str, Any] = {"__builtins__": {}, "abs": np.abs, "min": np.minimum, "max": np.maximum}


def _compile(source: str, batch: bool) -> Any:
    """The function ``source`` (a ``lambda`` generated in this module) defines."""
    return eval(source, dict(_BATCH if batch else _SCALAR))


# -- reward terms -------------------------------------------------------------------------------------
def _norm(kind: str, weight: float, scale: float, x: str, slot: int) -> str:
    if kind == "abs":
        return f"-{weight!r} * abs({x}) / {scale!r}"
    if kind == "squared":
        q = f"_q{slot}"
        return f"-{weight!r} * (({q} := ({x}) / {scale!r}) * {q})"
    return f"{weight!r} * ({x}) / {scale!r}"


def _term_source(term: RewardTerm, index: Mapping[str, int], action_inputs: Sequence[str], slot: int) -> str:
    """One term as a Python expression over ``s`` (signals), ``u`` (inputs), ``p`` (previous inputs)."""
    if term.alive is not None:
        return repr(float(term.alive))
    if term.tracking is not None:
        t = term.tracking
        return _norm(t.norm, t.weight, t.scale, f"s[{index[t.output]}] - s[{index[t.reference]}]", slot)
    if term.effort is not None:
        e = term.effort
        return _norm(e.norm, e.weight, e.scale, f"u[{action_inputs.index(e.name)}]", slot)
    if term.rate is not None:
        r, i = term.rate, action_inputs.index(term.rate.name)
        return _norm(r.norm, r.weight, r.scale, f"u[{i}] - p[{i}]", slot)
    assert term.signal is not None  # RewardTerm's validator admits exactly these kinds
    g = term.signal
    return _norm(g.norm, g.weight, g.scale, f"s[{index[g.name]}]", slot)


def terms_source(terms: Sequence[RewardTerm], index: Mapping[str, int], action_inputs: Sequence[str]) -> str:
    """The weighted sum of ``terms`` as ``lambda s, u, p: ...`` (penalty norms negative)."""
    body = " + ".join(f"({_term_source(t, index, action_inputs, k)})" for k, t in enumerate(terms))
    return f"lambda s, u, p: {body or '0.0'}"


def reward_terms(terms: Sequence[RewardTerm], index: Mapping[str, int], action_inputs: Sequence[str]) -> Term:
    """The weighted sum of built-in terms as one function over lists of floats."""
    return _compile(terms_source(terms, index, action_inputs), batch=False)  # type: ignore[no-any-return]


def batch_reward_terms(
    terms: Sequence[RewardTerm], index: Mapping[str, int], action_inputs: Sequence[str]
) -> Callable[..., Any]:
    """:func:`reward_terms` over transposed ``(signals, n)`` arrays: one value per env (or one
    float when every term is constant)."""
    return _compile(terms_source(terms, index, action_inputs), batch=True)  # type: ignore[no-any-return]


# -- observations -----------------------------------------------------------------------------------
def observation_source(
    raw: Sequence[str], centre: Sequence[float], inverse_half: Sequence[float], clip: float | None
) -> str:
    """``lambda s, u, nz: [...]``: each raw element (an expression over ``s``, ``u`` and ``nz``)
    scaled by ``(x - centre) * inverse_half`` and clipped to ``[-clip, clip]`` when given."""
    terms = [f"({x} - {c!r}) * {k!r}" for x, c, k in zip(raw, centre, inverse_half)]
    if clip is not None:
        terms = [f"min(max({t}, {-clip!r}), {clip!r})" for t in terms]
    return f"lambda s, u, nz: [{', '.join(terms)}]"


def observation(source: str) -> Observe:
    """The observation function of :func:`observation_source` over lists of floats."""
    return _compile(source, batch=False)  # type: ignore[no-any-return]


def batch_observation(source: str) -> Callable[..., list[Any]]:
    """The observation function of :func:`observation_source` over transposed batch columns."""
    return _compile(source, batch=True)  # type: ignore[no-any-return]


# -- termination --------------------------------------------------------------------------------------
def termination(
    bounds: Mapping[str, tuple[float | None, float | None]], index: Mapping[str, int]
) -> Terminate:
    """``reason(signals)``: ``"bounds:<name>"`` of the first bound a signal leaves, else None.

    Written ``not (lo <= x <= hi)`` so that a NaN signal also counts as outside its bounds.
    """
    checks = []
    for name, (lo, hi) in bounds.items():
        i = index[name]
        if lo is not None and hi is not None:
            checks.append((f"not ({float(lo)!r} <= s[{i}] <= {float(hi)!r})", f"bounds:{name}"))
        elif lo is not None:
            checks.append((f"not (s[{i}] >= {float(lo)!r})", f"bounds:{name}"))
        elif hi is not None:
            checks.append((f"not (s[{i}] <= {float(hi)!r})", f"bounds:{name}"))
    body = "None"
    for condition, reason in reversed(checks):
        body = f"({reason!r} if {condition} else {body})"
    return _compile(f"lambda s: {body}", batch=False)  # type: ignore[no-any-return]
