"""``fmu-bridge init``: a commented starting experiment written from an FMU's model description.

Nobody should type variable names by hand: inputs become actions, outputs observations,
parameters are listed with their defaults, and bounds are filled in where the FMU declares
them (and marked TODO where it does not).
"""

from __future__ import annotations

import math
from pathlib import Path

from bridge.fmu.vocab import ModelInfo, Variable


def _num(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "null"
    return repr(float(value))


def _comment(var: Variable) -> str:
    parts = [p for p in (var.unit and f"[{var.unit}]", var.description) if p]
    return f"  # {' '.join(parts)}" if parts else ""


def starting_config(fmu: str | Path, *, relative_to: Path | None = None) -> str:
    """The YAML text of a starting experiment for ``fmu``."""
    from bridge.fmu import read_model_info  # FMPy only where an FMU is read

    info = read_model_info(fmu)
    path = Path(fmu).resolve()
    try:
        shown = path.relative_to(relative_to.resolve()) if relative_to else path
    except ValueError:
        shown = path
    inputs = [v for v in info.variables.values() if v.causality == "input" and v.is_numeric]
    outputs = [v for v in info.variables.values() if v.causality == "output" and v.is_numeric]
    lines = _header(info, shown)
    lines += _parameters(info)
    lines += _actions(inputs)
    lines += _observations(outputs)
    lines += _reward_and_termination(outputs)
    return "\n".join(lines) + "\n"


def _header(info: ModelInfo, shown: Path) -> list[str]:
    de = info.default_experiment
    step = de.step_size_s or 0.01
    duration = (de.stop_time_s or 10.0) - (de.start_time_s or 0.0)
    return [
        f"# Experiment for {info.model_name} (FMI {info.fmi_version}, "
        f"{'/'.join(i.upper() for i in info.interfaces)})",
        f"# written by `fmu-bridge init` from {shown.name}; check it with `fmu-bridge check <this file>`.",
        f"name: {info.model_name.lower()}",
        "",
        "model:",
        f"  fmu: {shown}",
        f"  step_size: {step!r}          # FMU step, s"
        + ("" if de.step_size_s else "  (TODO: the FMU declares none)"),
        f"  sampling_time: {step!r}      # one agent sample; a whole multiple of step_size",
        f"  episode_duration: {duration!r}   # s; the episode is truncated after this",
        "  reset_policy: auto          # restore | reset | reinstantiate | auto",
    ]


def _actions(inputs: list[Variable]) -> list[str]:
    if not inputs:
        return ["# The FMU has no numeric inputs: an agent cannot act on it.", "actions:", "  inputs: []", ""]
    lines = [
        "actions:",
        f"  inputs: [{', '.join(v.name for v in inputs)}]",
        "  type: continuous            # the agent acts in [-1, 1], mapped onto [low, high]",
        "  low:",
    ]
    for v in inputs:
        todo = "" if v.min is not None and math.isfinite(v.min) else "  # TODO: the FMU declares no min"
        lines.append(f"    {v.name}: {_num(v.min) if todo == '' else '-1.0'}{todo or _comment(v)}")
    lines.append("  high:")
    for v in inputs:
        todo = "" if v.max is not None and math.isfinite(v.max) else "  # TODO: the FMU declares no max"
        lines.append(f"    {v.name}: {_num(v.max) if todo == '' else '1.0'}{todo}")
    return [*lines, ""]


def _observations(outputs: list[Variable]) -> list[str]:
    lines = ["observations:", f"  outputs: [{', '.join(v.name for v in outputs)}]"]
    lines += [
        "  scale: auto                 # from the FMU's min/max or nominal; or {name: [low, high]}",
        "  history: 1                  # stack the last k samples",
        "",
    ]
    for v in outputs:
        lines.insert(-3, f"  #   {v.name}{_comment(v).replace('  #', ':')}")
    return lines


def _reward_and_termination(outputs: list[Variable]) -> list[str]:
    first = outputs[0].name if outputs else "y"
    return [
        "reward:                        # built-in terms, an expression, or a Python callable",
        "  terms:",
        "    - alive: 1.0",
        f"    # - signal: {{name: {first}, norm: squared, weight: 1.0}}",
        f'  # expression: "1.0 - abs({first})"',
        "  termination_penalty: 0.0",
        "",
        "termination:",
        "  bounds: {}                  # e.g. {" + first + ": [-1.0, 1.0]}",
        "  on_fmu_terminate: true",
        "",
    ]


def _parameters(info: ModelInfo) -> list[str]:
    params = [
        v
        for v in info.variables.values()
        if v.causality == "parameter" and v.variability != "constant" and v.settable_at_init
    ]
    if not params:
        return [""]
    lines = [
        "  parameters: {}              # values for every episode; draw them per episode under",
        "                              # randomization.parameters. The FMU's parameters and defaults:",
    ]
    for v in params:
        value = v.start if not isinstance(v.start, str) else repr(v.start)
        lines.append(f"  #   {v.name}: {value}{_comment(v)}")
    return [*lines, ""]
