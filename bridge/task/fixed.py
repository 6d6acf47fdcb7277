"""Physical values for fixed policies (``zero``, ``start``, ``constant:V``): the action that applies
them exactly, and what ``zero`` and ``start`` mean.

``zero`` is no change: 0 on every FMU input and the FMU's start value on every tunable parameter.
``start`` runs the model as exported: every input at its declared start value, parameters
untouched (FMPy's ``simulate_fmu`` without inputs does the same).
A physical value reaches the FMU exactly (an :class:`~bridge.task.core.ExactAction` carries it past
the action mapping); a value outside an input's bounds, or between the levels of a discrete
action, is changed to the nearest allowed value with one warning naming the value, the bound and
the variable. ``simulate``, ``check`` and ``evaluate`` all use these.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from bridge.experiment.validate import action_bounds
from bridge.task.core import ExactAction, Task

_log = logging.getLogger(__name__)


def zero_values(task: Task) -> list[float]:
    """``zero``: 0 on each FMU input, the start value on each tunable parameter (no change)."""
    values = []
    for name in task.action_inputs:
        var = task.variables[name]
        start = var.start if isinstance(var.start, int | float) else 0.0
        values.append(float(start) if var.causality == "parameter" else 0.0)
    return values


FIXED_POLICIES = ("zero", "start", "random", "constant:VALUE")


def is_fixed_policy(spec: str) -> bool:
    """Whether ``spec`` names a fixed policy (``constant:`` with any value; its number is checked
    where the policy is made)."""
    return spec in FIXED_POLICIES[:3] or spec.startswith("constant:")


def unknown_policy(spec: str) -> str:
    """The message for an unknown fixed policy ``spec``."""
    return f"--policy {spec!r} is unknown; use {', '.join(FIXED_POLICIES[:-1])} or {FIXED_POLICIES[-1]}"


def start_values(task: Task) -> list[float]:
    """``start``: each action input at its declared start value (the model as exported; an input
    or parameter without a numeric start is at 0)."""
    values = []
    for name in task.action_inputs:
        start = task.variables[name].start
        values.append(float(start) if isinstance(start, int | float) else 0.0)
    return values


def physical_action(task: Task, values: list[float], label: str) -> Any:
    """The action that applies the physical ``values`` (one per action input) exactly; a value the
    action space cannot apply is changed to the nearest one it can, with one warning per input
    that starts with ``label`` (what the user asked for, e.g. ``--policy constant:2.5``)."""
    mapping = task.action_mapping
    names = task.action_inputs
    if mapping.kind == "continuous":
        applied = []
        for i, (name, value) in enumerate(zip(names, values)):
            low, high = action_bounds(task.experiment, task.variables[name])
            low = mapping.centre[i] - mapping.half[i] if low is None else float(low)
            high = mapping.centre[i] + mapping.half[i] if high is None else float(high)
            target = min(max(value, low), high)
            if target != value:
                bound = "maximum" if value > high else "minimum"
                _warn(label, name, value, f"outside its bounds [{low:g}, {high:g}]: its {bound} {target:g}")
            applied.append(target)
        return ExactAction(task.action_for_inputs(applied), applied)
    if mapping.kind == "discrete":
        rows = np.asarray(mapping.table, dtype=np.float64)
        index = int(np.argmin(np.abs(rows - np.asarray(values)).sum(axis=1)))
        for j, name in enumerate(names):
            if rows[index, j] != values[j]:
                column = sorted(set(rows[:, j].tolist()))
                _warn(label, name, values[j], f"not one of its levels {column}: {rows[index, j]:g}")
        return index
    picks = []
    for name, value, levels in zip(names, values, mapping.levels):
        k = int(np.argmin(np.abs(levels - value)))
        if levels[k] != value:
            _warn(label, name, value, f"not one of its levels {levels.tolist()}: {levels[k]:g}")
        picks.append(k)
    return np.array(picks)


def _warn(label: str, name: str, value: float, what: str) -> None:
    _log.warning("%s: %g on %s is %s is applied instead", label, value, name, what)
