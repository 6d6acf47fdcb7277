"""How long a client waits for a node: deadlines that follow the plant's measured speed.

A node's plant may answer in microseconds or take seconds a step and minutes to initialise. A
client waits for the answer to a step or a reset until the longest of:

- ``timeout_s``, the floor (``training.remote.timeout_s``; ``timeout_s`` in Python): what the
  network and a loaded machine may add to a fast plant;
- the node's own deadline plus a slack (``step_timeout_s`` in its ``info``: ``fmu-bridge node
  --step-timeout``, or its ``model.isolation.timeout``): the node reports a hung FMU itself at
  that deadline, with more to say than a client's timeout, so the client waits to hear it;
- a margin times the slowest answer measured by this client: ``STEP_MARGIN`` times its slowest
  step, ``RESET_MARGIN`` times its slowest reset (a reset may initialise the FMU again).

A reset that outlasts its deadline is not given up while the node says it works on it
(``bridge.net.client``): the node's first reset initialises its FMU, which takes as long as the
model needs (an isolated node's first reset has no deadline of its own, as in
``IsolatedFmuPlant``). This module holds the figures and says them in errors; it has no Zenoh.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from typing import Any, Literal

from bridge.errors import ConfigError

STEP_MARGIN = 4.0  # a step may take this many times the slowest one measured
RESET_MARGIN = 4.0  # a reset may take this many times the slowest one measured (as IsolatedFmuPlant)
NODE_SLACK = 0.25  # the node's own verdict may come this fraction of its deadline late (at least 1 s)
SETTINGS = (
    "timeout_s (training.remote.timeout_s) is the floor, for a slow network; a plant slower than the "
    "node's own deadline needs a longer `fmu-bridge node --step-timeout` (or model.isolation.timeout)"
)

Call = Literal["step", "reset"]


class Deadlines:
    """A client's deadlines for one node; ``stepped`` and ``reset_took`` feed the measured figures.

    Args:
        floor_s: ``timeout_s``, the shortest deadline, in seconds.
        node_s: the node's own deadline for a call (its ``step_timeout_s``; 0 if it names none).
    """

    def __init__(self, floor_s: float, node_s: float = 0.0) -> None:
        if not (isinstance(floor_s, float | int) and math.isfinite(floor_s) and floor_s > 0):
            raise ConfigError(
                f"timeout_s must be a finite number of seconds > 0, got {floor_s!r}; it is the "
                "shortest a client waits for a node's answer (training.remote.timeout_s)"
            )
        self.floor_s = float(floor_s)
        self.node_s = node_deadline_s({"step_timeout_s": node_s})
        self.slowest = {"step": 0.0, "reset": 0.0}
        self._lock = threading.Lock()  # answers are measured on Zenoh's thread

    def stepped(self, seconds: float) -> None:
        """A step was answered ``seconds`` after its action was sent."""
        self._measured("step", seconds)

    def reset_took(self, seconds: float) -> None:
        """A reset was answered ``seconds`` after it was asked."""
        self._measured("reset", seconds)

    def _measured(self, call: Call, seconds: float) -> None:
        with self._lock:
            self.slowest[call] = max(self.slowest[call], seconds)

    def step_s(self) -> float:
        """How long the next step may take, in seconds."""
        return self._deadline("step")

    def reset_s(self) -> float:
        """How long the next reset may take before the client asks whether the node works on it."""
        return self._deadline("reset")

    def _node_term_s(self) -> float:
        return self.node_s + max(1.0, NODE_SLACK * self.node_s) if self.node_s > 0 else 0.0

    def _deadline(self, call: Call) -> float:
        margin = STEP_MARGIN if call == "step" else RESET_MARGIN
        return max(self.floor_s, self._node_term_s(), margin * self.slowest[call])

    def explain(self, call: Call) -> str:
        """The deadline of ``call`` and where it comes from, for an error message."""
        margin = STEP_MARGIN if call == "step" else RESET_MARGIN
        parts = [f"timeout_s = {self.floor_s:g} s"]
        if self.node_s > 0:
            slack_s = self._node_term_s() - self.node_s
            parts.append(f"the node's own deadline {self.node_s:g} s + {slack_s:g} s")
        slowest = self.slowest[call]
        measured = f"{slowest:.3g} s" if slowest > 0 else "none yet"
        parts.append(f"{margin:g} x the slowest {call} measured ({measured})")
        return f"the deadline {self._deadline(call):.3g} s is the longest of " + ", ".join(parts)


def node_deadline_s(description: Mapping[str, Any]) -> float:
    """A node's own deadline for a call: the ``step_timeout_s`` of its ``info`` (0 if it names
    none, or no positive finite number)."""
    value = description.get("step_timeout_s", 0.0)
    ok = isinstance(value, float | int) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok and value > 0 else 0.0
