"""Evaluation metrics of one episode, from its trace.

Integrals use the rectangle rule over the samples after each action (``dt`` = sampling time),
matching how a sampled controller is judged: IAE = sum |e| dt, ISE = sum e^2 dt,
ITAE = sum t |e| dt with t measured from the episode start.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
MAX_STEPS = 10  # more reference changes than this: a moving reference, not a step sequence


@dataclass
class Trace:
    """What happened in one episode, sample by sample (index 0 is the state after reset)."""

    time_s: FloatArray
    signals: dict[str, FloatArray]
    inputs: dict[str, FloatArray]
    rewards: FloatArray
    reason: str | None
    terminated: bool
    scenario: str = ""
    extra: dict[str, Any] = field(default_factory=dict)  # the policy's own counts (``episode_stats``)

    @property
    def dt(self) -> float:
        return float(self.time_s[1] - self.time_s[0]) if len(self.time_s) > 1 else 0.0


def episode_metrics(trace: Trace) -> dict[str, Any]:
    return {
        "return": float(np.sum(trace.rewards)),
        "length": len(trace.rewards),
        "reason": trace.reason or "",
        "terminated": trace.terminated,
    }


def tracking_metrics(error: FloatArray, time_s: FloatArray, dt: float) -> dict[str, float]:
    """IAE, ISE, ITAE, RMSE and max |e| of a tracking error sampled at ``time_s``."""
    if error.size == 0:
        return {k: math.nan for k in ("iae", "ise", "itae", "rmse", "max_abs_error")}
    t = time_s - time_s[0]
    absolute = np.abs(error)
    return {
        "iae": float(np.sum(absolute) * dt),
        "ise": float(np.sum(error**2) * dt),
        "itae": float(np.sum(t * absolute) * dt),
        "rmse": float(np.sqrt(np.mean(error**2))),
        "max_abs_error": float(np.max(absolute)),
    }


def step_response(
    output: FloatArray, reference: FloatArray, time_s: FloatArray, *, band: float = 0.02, tail: float = 0.1
) -> dict[str, float]:
    """Overshoot [%], rise time (10-90 %), settling time (into +-band of the final reference) and
    steady-state error (mean over the last ``tail`` fraction) for the response to the reference's
    last change; for a reference that never changes, to the step from the initial output to the
    reference. NaN where undefined (no step at all, never reached, never settled, or a reference
    that keeps moving, such as a sine, where a step response means nothing)."""
    change = np.flatnonzero(np.abs(np.diff(reference)) > 0)
    if change.size > MAX_STEPS:
        n_tail = max(1, round(tail * len(output)))
        return {
            "steady_state_error": float(np.mean(reference[-n_tail:] - output[-n_tail:])),
            "overshoot_pct": math.nan,
            "rise_time_s": math.nan,
            "settling_time_s": math.nan,
        }
    start = int(change[-1]) + 1 if change.size else 0
    initial = float(reference[start - 1]) if change.size else float(output[0])
    final = float(reference[-1])
    span = final - initial
    y, t = output[start:], time_s[start:] - time_s[start]
    n_tail = max(1, round(tail * len(output)))
    result = {"steady_state_error": float(np.mean(reference[-n_tail:] - output[-n_tail:]))}
    if span == 0 or y.size == 0:
        return {**result, "overshoot_pct": math.nan, "rise_time_s": math.nan, "settling_time_s": math.nan}
    progress = (y - initial) / span
    result["overshoot_pct"] = float(max(0.0, progress.max() - 1.0) * 100.0)
    above10, above90 = np.flatnonzero(progress >= 0.1), np.flatnonzero(progress >= 0.9)
    result["rise_time_s"] = (
        float(t[above90[0]] - t[above10[0]]) if above10.size and above90.size else math.nan
    )
    outside = np.flatnonzero(np.abs(y - final) > band * abs(span))
    if outside.size == 0:
        result["settling_time_s"] = 0.0
    elif outside[-1] + 1 < len(y):
        result["settling_time_s"] = float(t[outside[-1] + 1])
    else:
        result["settling_time_s"] = math.nan
    return result


def effort_metrics(u: FloatArray) -> dict[str, float]:
    """sum |u|, sum u^2 and total variation sum |u_k - u_(k-1)|."""
    return {
        "effort_abs": float(np.sum(np.abs(u))),
        "effort_sq": float(np.sum(u**2)),
        "total_variation": float(np.sum(np.abs(np.diff(u)))) if u.size > 1 else 0.0,
    }


def constraint_metrics(
    values: FloatArray, low: float | None, high: float | None, dt: float
) -> dict[str, float]:
    """Samples outside [low, high] and the time spent outside."""
    outside = np.zeros(values.shape, dtype=bool)
    if low is not None:
        outside |= values < low
    if high is not None:
        outside |= values > high
    count = int(np.sum(outside))
    return {"violations": count, "violation_time_s": count * dt}


@dataclass
class MetricSpec:
    """Which metrics to compute (from an experiment's ``evaluation.metrics`` section)."""

    tracking: list[tuple[str, str]] = field(default_factory=list)  # (output, reference)
    effort: list[str] = field(default_factory=list)  # action inputs
    constraints: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)
    success: str | None = None  # an expression over metric names, e.g. "episode_return >= 475"
    user: list[Callable[[Trace], Mapping[str, float] | float]] = field(default_factory=list)
    band: float = 0.02
    duration_s: float | None = None  # the full episode, for ``iae_held``
    scenario_durations: dict[str, float] = field(default_factory=dict)  # scenarios of their own length


def held_iae(error: FloatArray, dt: float, duration_s: float) -> float:
    """IAE over the full episode duration: an episode that ended early keeps its last |error| until
    ``duration_s`` after the start, so leaving the envelope early is not rewarded with a short sum.
    ``error`` holds one sample per action, each standing for ``dt`` seconds."""
    if error.size == 0:
        return math.nan
    remaining = max(0.0, duration_s - error.size * dt)
    return float(np.sum(np.abs(error)) * dt + abs(error[-1]) * remaining)


def compute(trace: Trace, spec: MetricSpec) -> dict[str, Any]:
    """Every configured metric of one episode, flat (``omega.iae``, ``voltage.effort_sq``, ...)."""
    row: dict[str, Any] = episode_metrics(trace)
    dt = trace.dt
    for output, reference in spec.tracking:
        y, r = trace.signals[output][1:], trace.signals[reference][1:]
        t = trace.time_s[1:]
        for key, value in {
            **tracking_metrics(r - y, t, dt),
            **step_response(y, r, t, band=spec.band),
        }.items():
            row[f"{output}.{key}"] = value
        duration_s = spec.scenario_durations.get(trace.scenario, spec.duration_s)
        if duration_s is not None:
            row[f"{output}.iae_held"] = held_iae(r - y, dt, duration_s)
    for name in spec.effort:
        for key, value in effort_metrics(trace.inputs[name]).items():
            row[f"{name}.{key}"] = value
    for name, (low, high) in spec.constraints.items():
        for key, value in constraint_metrics(trace.signals[name][1:], low, high, dt).items():
            row[f"{name}.{key}"] = value
    row.update({k: v for k, v in trace.extra.items() if isinstance(v, int | float)})  # e.g. solver fallbacks
    for fn in spec.user:
        result = fn(trace)
        name = getattr(fn, "__name__", "user")
        if isinstance(result, Mapping):
            row.update({f"{name}.{k}": float(v) for k, v in result.items()})
        else:
            row[name] = float(result)
    if spec.success:
        row["success"] = success(spec.success, row)
    return row


def metric_alias(name: str) -> str:
    """How a metric is named in a success expression: dots become underscores, ``return`` is
    ``episode_return`` (a Python keyword cannot be a name)."""
    return "episode_return" if name == "return" else name.replace(".", "_")


def success(expression: str, row: Mapping[str, Any]) -> bool:
    """Evaluate a success condition (e.g. ``episode_return >= 475 and not terminated``) over the
    numeric metrics of ``row`` with bridge's safe expression evaluator."""
    from bridge.task.expr import compile_expression

    numeric = {metric_alias(k): float(v) for k, v in row.items() if isinstance(v, int | float)}
    compiled = compile_expression(expression, list(numeric), where="evaluation.metrics.success")
    return bool(compiled(list(numeric.values())))


def aggregate(rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Mean of every numeric metric over episodes (booleans as rates)."""
    keys = [k for k, v in rows[0].items() if isinstance(v, int | float)] if rows else []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a metric undefined in every episode stays NaN
        return {k: float(np.nanmean([float(r[k]) for r in rows])) for k in keys}
