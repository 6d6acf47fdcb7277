"""Python hooks referenced as ``module:function`` by experiments in the tests."""

from __future__ import annotations

from typing import Any

import numpy as np

from bridge.task.scenario import EpisodeSpec


def half_current(signals: dict[str, float]) -> float:
    return 0.5 * signals["current"]


def heavier_rotor(spec: EpisodeSpec, rng: np.random.Generator) -> EpisodeSpec:
    return spec.with_values(J=0.05)


def load_after_5(step: int, time_s: float, signals: dict[str, Any]) -> dict[str, float] | None:
    return {"load_torque": 0.25} if step >= 5 else None


def half_voltage(obs: Any, signals: dict[str, float]) -> Any:
    """A scripted policy: always +12 V on a +-24 V motor (action 0.5)."""
    return np.array([0.5], dtype=np.float32)


class _Counter:
    calls = 0


def fails_after_200(signals: dict[str, float]) -> float:
    """A reward that breaks mid-training (a crash inside the run)."""
    _Counter.calls += 1
    if _Counter.calls > 200:
        raise RuntimeError("the reward broke at its 201st call")
    return 0.0


def interrupts_after_200(signals: dict[str, float]) -> float:
    """A reward during which Ctrl-C arrives mid-training."""
    _Counter.calls += 1
    if _Counter.calls > 200:
        raise KeyboardInterrupt
    return 0.0


class SeenSignals:
    """What ``record_signals`` was handed, one dict per call (the sensor-path tests read it)."""

    calls: list[dict[str, float]] = []


def record_signals(obs: Any, signals: dict[str, float]) -> Any:
    """A scripted policy that keeps the signals it reads and applies +12 V (action 0.5)."""
    SeenSignals.calls.append(dict(signals))
    return np.array([0.5], dtype=np.float32)
