"""Inference latency in bounded memory: the last ``capacity`` samples in a ring buffer."""

from __future__ import annotations

import numpy as np


class LatencyWindow:
    """Keeps the most recent ``capacity`` latencies (seconds) and counts all of them.

    A long-running agent observes for days; its statistics describe the recent window (by
    default the last 65,536 observations: 22 minutes at 50 Hz) in a fixed 512 kB.
    """

    def __init__(self, capacity: int = 65_536) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self._values = np.zeros(capacity, dtype=np.float64)
        self.count = 0

    @property
    def capacity(self) -> int:
        return len(self._values)

    def append(self, latency_s: float) -> None:
        self._values[self.count % len(self._values)] = latency_s
        self.count += 1

    def __len__(self) -> int:
        return min(self.count, len(self._values))

    def window(self) -> np.ndarray:
        """The kept latencies (at most ``capacity``), in no particular order."""
        return self._values[: len(self)]

    def quantile(self, q: float) -> float:
        """The ``q`` quantile of the window (lower value, no interpolation); NaN when empty."""
        kept = self.window()
        if not len(kept):
            return float("nan")
        return float(np.sort(kept)[int(q * (len(kept) - 1))])
