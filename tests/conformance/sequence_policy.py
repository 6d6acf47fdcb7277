"""The conformance matrix's fixed action sequence, as an agent any path can load by name.

``python:tests.conformance.sequence_policy:SEQUENCE`` (an ``evaluation.baselines`` entry of
``type: python``) acts the same row ``k`` at sample ``k`` of every episode, whatever it observes,
so ``evaluate`` in worker processes and a deployed agent drive the model as the matrix's own loop
does. It keeps what it observed (this process's), for a path that has no other record of it, and
can hold its answer at an episode's end (a lockstep node steps as long as actions come).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any

import numpy as np

CALLABLE = "tests.conformance.sequence_policy:SEQUENCE"


def action_row(k: int, n: int) -> np.ndarray:
    """Row ``k`` of the sequence for ``n`` inputs: in [-1, 1], moving every input."""
    j = np.arange(n, dtype=np.float32)
    return np.sin(np.float32(0.7) * np.float32(k) + np.float32(1.3) * j).astype(np.float32)


class Sequence:
    """``fn(obs, signals) -> action`` with ``reset(task, seed)``, as ``PythonPolicy`` calls it."""

    def __init__(self) -> None:
        self.k = 0
        self.n = 0
        self.episodes: list[list[np.ndarray]] = []  # what it observed, per episode
        # hold_after observations into an episode, the next action waits (``held`` set) until
        # ``release``: a node that never ends an episode steps no further meanwhile
        self.hold_after: int | None = None
        self.held, self.release = threading.Event(), threading.Event()

    def reset(self, task: Any, seed: int | None) -> None:
        self.k, self.n = 0, len(task.action_inputs)
        self.episodes.append([])

    def __call__(self, obs: Any, signals: Mapping[str, float]) -> np.ndarray:
        self.episodes[-1].append(np.array(obs, dtype=np.float64))
        if len(self.episodes[-1]) == self.hold_after:
            self.held.set()
            self.release.wait(timeout=120.0)
            self.release.clear()
        row = action_row(self.k, self.n)
        self.k += 1
        return row


SEQUENCE = Sequence()
