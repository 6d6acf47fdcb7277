"""Which clock settings an experiment may make, checked from the model description alone (no FMU
loaded, no FMPy): the importer sets intervals only for fixed and tunable input clocks with an
``intervalDecimal`` and schedules only triggered input clocks (FMI 3.0 §2.2.9), and only where the
clocks tick here. :mod:`bridge.fmu.clocks` applies the same rules when it opens an FMU;
``fmu-bridge check`` applies them before saying "config ok"."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from bridge.errors import ConfigError
from bridge.fmu.vocab import ModelInfo, Variable


def clock_driver_needed(info: ModelInfo, interface: str) -> bool:
    """Whether the instance runs its clocks: scheduled execution, or FMI 3.0 model exchange or
    co-simulation in event mode with at least one input clock."""
    if interface == "se":
        return True
    inputs = any(v.causality == "input" for v in info.clocks)
    return inputs and (interface == "me" or (interface == "cs" and info.has_event_mode))


def check_settings(
    info: ModelInfo,
    interface: str,
    intervals: Mapping[str, float] | None,
    schedule: Mapping[str, Sequence[float]] | None,
) -> None:
    """Refuse clock intervals and schedules as :class:`Model` does when it opens, without opening it
    (``fmu-bridge check`` says "config ok" only for what will run)."""
    if not (intervals or schedule):
        return
    chosen = interface
    if interface == "auto":
        chosen = next((i for i in ("cs", "me", "se") if i in info.interfaces), "cs")
    if chosen not in info.interfaces:
        return  # the model's own check names the interfaces there are
    if not clock_driver_needed(info, chosen):
        raise ConfigError(
            f"{info.model_name}: clock_intervals and clock_schedule need FMI 3.0 input clocks "
            f"in co-simulation with event mode or in scheduled execution; this FMU runs "
            f"FMI {info.fmi_version} {chosen.upper()} without them"
        )
    inputs = {v.name: v for v in info.clocks if v.causality == "input"}
    _check_intervals(info, inputs, intervals or {})
    _check_schedule(info, inputs, schedule or {})


def _check_intervals(
    info: ModelInfo, inputs: Mapping[str, Variable], intervals: Mapping[str, float]
) -> dict[str, float]:
    settable = [
        n
        for n, v in inputs.items()
        if v.clock and v.clock.interval_variability in ("fixed", "tunable") and v.clock.interval_s is not None
    ]
    checked = {}
    for name, interval in intervals.items():
        if name not in settable:
            raise ConfigError(
                f"{info.model_name}: the interval of clock {name!r} cannot be set: only fixed and tunable "
                f"input clocks with an intervalDecimal take one from the importer; here: {settable or 'none'}"
            )
        if (
            isinstance(interval, bool)
            or not isinstance(interval, (int, float))
            or not (math.isfinite(interval) and interval > 0)
        ):
            raise ConfigError(
                f"{info.model_name}: clock {name!r}: interval {interval!r} s; expected a number > 0"
            )
        checked[name] = float(interval)
    return checked


def _check_schedule(
    info: ModelInfo, inputs: Mapping[str, Variable], schedule: Mapping[str, Sequence[float]]
) -> dict[str, list[float]]:
    triggered = [n for n, v in inputs.items() if v.clock and v.clock.interval_variability == "triggered"]
    checked = {}
    for name, times in schedule.items():
        if name not in triggered:
            raise ConfigError(
                f"{info.model_name}: clock_schedule names {name!r}, which is not a triggered input clock; "
                f"scheduled activations are for {triggered or 'none (this FMU has none)'}"
            )
        values = [float(t) for t in times]
        if any(not math.isfinite(t) for t in values) or values != sorted(values):
            raise ConfigError(
                f"{info.model_name}: clock_schedule.{name}: {list(times)} must be finite times in "
                f"increasing order (seconds)"
            )
        checked[name] = values
    return checked


__all__ = ["check_settings", "clock_driver_needed"]
