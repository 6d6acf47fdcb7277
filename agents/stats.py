"""Statistics a reviewer asks for: bootstrap confidence intervals, paired differences, seed spread.

Every agent in an evaluation sees the same seeds on the same scenarios, so agents are compared
**paired**: the difference of a metric between an agent and a named reference agent is taken
episode by episode (same scenario, same seed), and its mean gets a percentile bootstrap interval.
A difference whose interval excludes zero is a result; one whose interval includes zero is not.

The bootstrap is the plain percentile bootstrap over episodes (resampling with replacement,
``resamples`` draws from a generator seeded by ``seed``, so a report is reproducible). With fewer
than two values there is no interval: the bounds are NaN and the tables say ``n/a``.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
LEVEL = 0.95
RESAMPLES = 10_000
HIGHER_IS_BETTER = ("return", "success", "length")  # metric names (or suffixes) where more is better

_STATISTICS: dict[str, Callable[..., Any]] = {"mean": np.mean, "median": np.median}


def bootstrap_interval(
    values: Sequence[float] | FloatArray,
    statistic: str = "mean",
    *,
    level: float = LEVEL,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """The percentile bootstrap interval of ``statistic`` (``mean`` or ``median``) of ``values``.

    NaN values are left out; fewer than two values give ``(nan, nan)``.
    """
    x = np.asarray(values, dtype=np.float64)
    x = x[~np.isnan(x)]
    if x.size < 2:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    draws = x[rng.integers(0, x.size, size=(resamples, x.size))]
    stats = _STATISTICS[statistic](draws, axis=1)
    tail = (1.0 - level) / 2.0
    low, high = np.quantile(stats, [tail, 1.0 - tail])
    return float(low), float(high)


def higher_is_better(metric: str) -> bool:
    """Whether a larger value of ``metric`` is better (return, success, length); errors, effort
    and violations are better when smaller."""
    return metric.rsplit(".", maxsplit=1)[-1] in HIGHER_IS_BETTER or metric in HIGHER_IS_BETTER


def describe(values: Sequence[float], *, seed: int = 0) -> dict[str, float]:
    """Median and mean with their bootstrap intervals, and the spread (sample standard deviation)."""
    x = np.asarray(values, dtype=np.float64)
    x = x[~np.isnan(x)]
    if x.size == 0:
        return {
            k: math.nan
            for k in ("median", "median_low", "median_high", "mean", "mean_low", "mean_high", "std")
        }
    median_low, median_high = bootstrap_interval(x, "median", seed=seed)
    mean_low, mean_high = bootstrap_interval(x, "mean", seed=seed)
    return {
        "median": float(np.median(x)),
        "median_low": median_low,
        "median_high": median_high,
        "mean": float(np.mean(x)),
        "mean_low": mean_low,
        "mean_high": mean_high,
        "std": float(np.std(x, ddof=1)) if x.size > 1 else math.nan,
    }


def paired_differences(
    rows: Sequence[Mapping[str, Any]], reference: str, metric: str = "return", *, seed: int = 0
) -> list[dict[str, Any]]:
    """Per agent and scenario (and over all scenarios): the mean of ``metric(agent) - metric(reference)``
    over episodes paired by scenario and seed, its bootstrap interval, and wins/losses/ties (a win is
    an episode where the agent did better than the reference, by the metric's direction).

    ``rows`` are evaluation episode rows (``agent``, ``scenario``, ``seed`` and the metrics).
    """
    by_agent: dict[str, dict[tuple[str, int], float]] = defaultdict(dict)
    for row in rows:
        if metric in row:
            by_agent[row["agent"]][(row["scenario"], int(row["seed"]))] = float(row[metric])
    if reference not in by_agent:
        from bridge.errors import ConfigError

        raise ConfigError(
            f"reference agent {reference!r} is not among the evaluated agents {sorted(by_agent)} "
            f"(or has no metric {metric!r}); name one of them"
        )
    ref = by_agent[reference]
    sign = 1.0 if higher_is_better(metric) else -1.0
    out = []
    for agent, values in by_agent.items():
        if agent == reference:
            continue
        keys = sorted(k for k in values if k in ref)
        scenarios = sorted({s for s, _ in keys})
        groups = [(s, [k for k in keys if k[0] == s]) for s in scenarios]
        if len(scenarios) > 1:
            groups.append(("all", keys))
        for scenario, chosen in groups:
            diff = np.array([values[k] - ref[k] for k in chosen])
            low, high = bootstrap_interval(diff, "mean", seed=seed)
            better = sign * diff
            out.append(
                {
                    "agent": agent,
                    "reference": reference,
                    "scenario": scenario,
                    "metric": metric,
                    "episodes": len(chosen),
                    "difference": float(np.nanmean(diff)) if diff.size else math.nan,
                    "low": low,
                    "high": high,
                    "wins": int(np.sum(better > 0)),
                    "losses": int(np.sum(better < 0)),
                    "ties": int(np.sum(better == 0)),
                    "verdict": verdict(low, high, higher_is_better(metric)),
                }
            )
    return out


def verdict(low: float, high: float, higher_better: bool) -> str:
    """``better``/``worse`` when the interval of (agent - reference) excludes zero, else ``no difference
    shown``; ``n/a`` without an interval."""
    if math.isnan(low) or math.isnan(high):
        return "n/a"
    if low > 0 or high < 0:
        return "better" if (low > 0) == higher_better else "worse"
    return "no difference shown"


def interval_text(low: float, high: float) -> str:
    """``[low, high]`` with four significant digits, ``n/a`` without an interval."""
    if math.isnan(low) or math.isnan(high):
        return "n/a"
    return f"[{low:.4g}, {high:.4g}]"
