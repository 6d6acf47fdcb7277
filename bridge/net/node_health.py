"""A node's health: ``ok``, ``failed`` (the last episode ended by a plant error), ``unusable``
(the plant cannot step until the next reset: its FMU's initialisation failed, or its isolated
process died or was killed; the next reset starts it afresh) or ``hung`` (a call into the FMU
outlived the deadline and, in this process, cannot be interrupted)."""

from __future__ import annotations

import logging
from collections import Counter

from bridge.errors import PlantError, StepTimeout
from bridge.net.requests import redact

_log = logging.getLogger(__name__)


class Health:
    """What ``info`` reports as ``health`` and ``health_detail``; counts ``hung`` and ``fmu_errors``."""

    def __init__(self, node: str, deadline_s: float, counters: Counter[str]) -> None:
        self.node, self.deadline_s, self.counters = node, deadline_s, counters
        self.state, self.detail = "ok", ""

    @property
    def is_hung(self) -> bool:
        return self.state == "hung"

    def report(self, unusable: str | None) -> tuple[str, str]:
        """``(health, health_detail)`` as ``info`` says them; ``unusable`` is the plant's own
        ``Plant.unusable`` (read at each ``info``, so a child that died while idle shows too)."""
        if self.state == "hung" or unusable is None:
            return self.state, self.detail
        detail = redact(unusable if not self.detail else f"{unusable} (after: {self.detail})")
        return "unusable", detail

    def ok(self) -> None:
        self.state, self.detail = "ok", ""

    def failed(self, exc: PlantError, episode: int, step: int) -> str:
        """A plant error ended ``episode`` at ``step``; the ERROR frame's text: the cause in the
        plant's words and the FMU's log (the client puts both in its own error), paths left out."""
        self.counters["hung" if isinstance(exc, StepTimeout) else "fmu_errors"] += 1
        self.state = "failed"
        self.detail = redact(f"episode {episode} ended at step {step}: {exc.detail}")
        _log.warning("node %s: episode %d ended by a plant error: %s", self.node, episode, exc)
        log = getattr(exc, "log", [])
        return redact(
            exc.detail + ("\nFMU log (most recent last):\n  " + "\n  ".join(log[-20:]) if log else "")
        )

    def hung(self, what: str, elapsed_s: float, deadline_s: float | None = None) -> str:
        """``what`` has not returned for ``elapsed_s``: the node is unhealthy until restarted.
        ``deadline_s``: the one that passed (a reset's follows the slowest reset measured)."""
        self.counters["hung"] += 1
        self.state = "hung"
        deadline = self.deadline_s if deadline_s is None else deadline_s
        why = (
            "the node's --step-timeout: a slower plant needs a longer one"
            if deadline <= self.deadline_s
            else f"4 x the slowest reset so far, longer than the node's --step-timeout {self.deadline_s:g} s"
        )
        self.detail = (
            f"the FMU has not returned from {what} for {elapsed_s:.1f} s (deadline {deadline:g} s, {why}); "
            "it cannot be interrupted in this process: restart the node, and run unstable FMUs with --isolate"
        )
        _log.error("node %s: %s", self.node, self.detail)
        return self.detail
