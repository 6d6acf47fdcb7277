"""``fmu-bridge init``: a commented starting experiment written from an FMU's model description.

Nobody should type variable names by hand, and nobody should have to edit the result before
``check`` accepts it. What becomes what:

- Real (Float) inputs: continuous actions, bounds from min/max, else a guess marked ``GUESS``;
- Integer, Boolean and Enumeration inputs: a ``multi_discrete`` action over levels inside their
  declared range or items when they are the only inputs, else held at their start values;
- no inputs: the same over tunable parameters, else an observation-only experiment;
- observations: the outputs, else the states (``x`` of ``der(x)``) and other locals.

Every name is written as a double-quoted YAML scalar, so any Modelica name (``a.b[1]``,
``der(x)``, ``'quoted name'``) reads back unchanged.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

from bridge.experiment.safe import safe_name
from bridge.experiment.validate import with_elements
from bridge.fmu.vocab import ModelInfo, Variable

#: Locals observed at most when a model has no outputs (Modelica models may have thousands).
MAX_OBSERVED = 12
INTEGER_TYPES = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64")
_TYPE_RANGES = {
    t: ((-(2 ** (b - 1)), 2 ** (b - 1) - 1) if t[0] == "I" else (0, 2**b - 1))
    for t, b in zip(INTEGER_TYPES, (8, 8, 16, 16, 32, 32, 64, 64))
}


def q(text: str) -> str:
    """``text`` as a double-quoted YAML scalar (JSON strings are valid YAML flow scalars)."""
    return json.dumps(text, ensure_ascii=False)


def _num(value: float) -> str:
    """``value`` as a YAML float that YAML 1.1 readers (PyYAML, ROS 2) read as a float too: they
    want a dot in the mantissa of an exponent form (``1.0e-06``, not ``1e-06``, a string there)."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        return f"{mantissa}.0e{exponent}"
    return {"inf": ".inf", "-inf": "-.inf", "nan": ".nan"}.get(text, text)


def _comment(var: Variable) -> str:
    parts = [p for p in (var.unit and f"[{var.unit}]", var.description) if p]
    text = " ".join(" ".join(str(p).split()) for p in parts)  # one line, whatever the XML holds
    return f"  # {text}" if text else ""


def starting_config(fmu: str | Path, *, relative_to: Path | None = None) -> str:
    """The YAML text of a starting experiment for ``fmu`` that ``fmu-bridge check`` accepts as is."""
    from bridge.fmu import read_model_info  # FMPy only where an FMU is read

    info = read_model_info(fmu)
    path = Path(fmu).resolve()
    try:
        shown = path.relative_to(relative_to.resolve()) if relative_to else path
    except ValueError:
        shown = path
    scalars = [v for v in with_elements(info.variables).values() if v.is_numeric and not v.dimensions]
    inputs = [v for v in scalars if v.causality == "input"]
    observed, observed_note = observations_for(scalars)
    lines = _header(info, shown)
    lines += _structural(info)
    lines += _clocks(info)
    lines += _parameters(info)
    lines += _actions(inputs, [v for v in scalars if _tunable(v)])
    lines += _observations(observed, observed_note)
    lines += _reward_and_termination(observed)
    return "\n".join(lines) + "\n"


def _tunable(var: Variable) -> bool:
    return var.causality == "parameter" and var.variability == "tunable"


def observations_for(scalars: Sequence[Variable]) -> tuple[list[Variable], str]:
    """The outputs; else the states and other locals; else the parameters; with a note on the choice."""
    outputs = [v for v in scalars if v.causality == "output"]
    if outputs:
        return outputs, ""
    names = {v.name for v in scalars}
    states = [v for v in scalars if f"der({v.name})" in names]
    locals_ = [v for v in scalars if v.causality == "local" and v not in states]
    chosen = (states + locals_)[:MAX_OBSERVED]
    if chosen:
        more = len(states) + len(locals_) - len(chosen)
        extra = f"; {more} more locals not shown (`fmu-bridge inspect -c local`)" if more else ""
        return chosen, f"# The FMU has no outputs: observing its states and local variables{extra}."
    rest = [v for v in scalars if v.causality not in ("input", "independent")][:MAX_OBSERVED]
    return rest, "# The FMU has no outputs or locals: observing its parameters (constant signals)."


#: Samples per episode ``init`` aims at: a long default experiment is sampled more coarsely (and,
#: beyond what a sample can span, shortened) so the written experiment passes ``check``.
TARGET_SAMPLES = 10_000
MAX_STEPS_PER_SAMPLE = 10_000  # FMU steps per sample before init shortens the episode instead


def episode_timing(info: ModelInfo) -> tuple[float, float, float, list[str]]:
    """(step size, sampling time, episode duration) for ``init``, and comment lines saying what was
    chosen and why, from the FMU's default experiment (step size, start and stop time).

    The step is the declared one (else 1/1000 of the declared duration, else 0.01 s); the sampling
    time is the step, or the smallest whole multiple of it giving at most TARGET_SAMPLES samples per
    episode; the episode is the default experiment's duration, shortened to TARGET_SAMPLES samples of
    MAX_STEPS_PER_SAMPLE steps when even that sampling cannot cover it. Every choice stays within
    the limits ``check`` applies (MAX_SAMPLES samples per episode and steps per sample).
    """
    de = info.default_experiment
    start = de.start_time_s or 0.0
    declared = (de.stop_time_s - start) if de.stop_time_s is not None else None
    duration = declared if declared is not None and declared > 0 and math.isfinite(declared) else None
    notes: list[str] = []
    if de.step_size_s and de.step_size_s > 0 and math.isfinite(de.step_size_s):
        step = de.step_size_s
    else:
        step = _nice(duration / 1000) if duration else 0.01
        notes.append(
            f"# step_size {step:g} s is a GUESS: the FMU declares none"
            + (f" (1/1000 of its default experiment, {duration:g} s)" if duration else "")
        )
    if duration is None:
        duration = 1000 * step if not de.step_size_s else max(10.0, step)
        notes.append(
            f"# episode_duration {duration:g} s: the FMU declares no stop time; set the one you need"
        )
    duration = max(duration, step)
    steps = duration / step
    per_sample = max(1, math.ceil(steps / TARGET_SAMPLES - 1e-9))
    if per_sample > MAX_STEPS_PER_SAMPLE:
        per_sample = MAX_STEPS_PER_SAMPLE
        shortened = _clean(TARGET_SAMPLES * per_sample * step)
        notes.append(
            f"# episode_duration: the default experiment runs {duration:g} s, {steps:.3g} FMU steps of "
            f"{step:g} s; shortened to {shortened:g} s ({TARGET_SAMPLES:,} samples of {per_sample:,} steps)"
        )
        duration = shortened
    sampling = _clean(per_sample * step)
    if per_sample > 1:
        notes.append(
            f"# sampling_time {sampling:g} s = {per_sample:,} FMU steps: at most {TARGET_SAMPLES:,} samples "
            f"per episode of {duration:g} s (sample faster for finer control, up to the step size)"
        )
    return step, sampling, _clean(duration), notes


def _nice(value: float) -> float:
    """``value`` rounded down to 1, 2 or 5 times a power of ten (a step size a person would pick)."""
    exponent = math.floor(math.log10(value))
    for mantissa in (5, 2, 1):
        if mantissa * 10.0**exponent <= value:
            return _clean(mantissa * 10.0**exponent)
    return _clean(10.0**exponent)


def _clean(value: float) -> float:
    """``value`` without float noise (``0.30000000000000004`` -> ``0.3``)."""
    return float(f"{value:.12g}")


def _header(info: ModelInfo, shown: Path) -> list[str]:
    step, sampling, duration, notes = episode_timing(info)
    start = info.default_experiment.start_time_s or 0.0
    return [
        f"# Experiment for {' '.join(info.model_name.split())} (FMI {info.fmi_version}, "
        f"{'/'.join(i.upper() for i in info.interfaces)})",
        f"# written by `fmu-bridge init` from {shown.name}; check it with `fmu-bridge check <this file>`.",
        f"name: {q(safe_name(info.model_name.lower()))}",
        "",
        "model:",
        f"  fmu: {q(str(shown))}",
        *[f"  {note}" for note in notes],
        f"  step_size: {_num(step)}          # FMU step, s",
        f"  sampling_time: {_num(sampling)}      # one agent sample; a whole multiple of step_size",
        f"  episode_duration: {_num(duration)}   # s; the episode is truncated after this",
        *([f"  start_time: {_num(start)}"] if start else []),
        *_reset_policy(info),
    ]


def _auto_interface(info: ModelInfo) -> str:
    """The interface ``model.interface: auto`` runs (as ``Model`` chooses it)."""
    return next(i for i in ("cs", "me", "se") if i in info.interfaces)


def _reset_policy(info: ModelInfo) -> list[str]:
    """The reset policy line; ``{state_file: PATH}`` is offered only where the FMU can save its state."""
    from bridge.fmu.serial import refusal

    line = "  reset_policy: auto          # restore | reset | reinstantiate | auto"
    why = refusal(info, _auto_interface(info)) if info.raw is not None else "unknown"  # type: ignore[arg-type]
    if why is None:
        return [f"{line} | {{state_file: PATH}}  (a state saved by `fmu-bridge state save`)"]
    return [line, "                              # (no state_file: this FMU cannot save its state to a file)"]


def _structural(info: ModelInfo) -> list[str]:
    """A commented ``structural_parameters`` line with the array sizes' start values, if any."""
    sizes = [
        v for v in info.variables.values() if v.causality == "structuralParameter" and v.start is not None
    ]
    if not sizes:
        return []
    values = ", ".join(f"{q(v.name)}: {v.start}" for v in sizes)
    return [
        f"  # structural_parameters: {{{values}}}  # array sizes, set in configuration mode; with",
        "  #   other sizes, name the elements that then exist (u[1]..u[n]) below (docs/arrays.md)",
    ]


def _clocks(info: ModelInfo) -> list[str]:
    """Commented ``clock_intervals`` / ``clock_schedule`` lines for the input clocks the importer may set."""
    from bridge.fmu.clock_rules import clock_driver_needed

    inputs = [v for v in info.clocks if v.causality == "input" and v.clock is not None]
    settable = [
        v
        for v in inputs
        if v.clock and v.clock.interval_variability in ("fixed", "tunable") and v.clock.interval_s is not None
    ]
    triggered = [v for v in inputs if v.clock and v.clock.interval_variability == "triggered"]
    if not (settable or triggered):
        return []
    auto = _auto_interface(info)
    ticking = [i for i in info.interfaces if clock_driver_needed(info, i)]
    if not ticking:
        return [f"  # clocks: {', '.join(q(v.name) for v in inputs)} do not tick here (see docs/clocks.md)"]
    lines = ["  # the FMU's clocks tick at their own times (docs/clocks.md); the importer may set:"]
    if auto not in ticking:
        lines.append(f"  # interface: {ticking[0]}     # clocks tick only there ({auto} is what auto runs)")
    if settable:
        values = ", ".join(
            f"{q(v.name)}: {_num(v.clock.interval_s)}" for v in settable if v.clock and v.clock.interval_s
        )
        lines.append(f"  # clock_intervals: {{{values}}}  # s, the FMU's own intervals")
    if triggered:
        first = info.default_experiment.start_time_s or 0.0
        lines.append(
            f"  # clock_schedule: {{{q(triggered[0].name)}: [{_num(first + 1.0)}]}}  # s from the start: "
            f"ticks of {', '.join(q(v.name) for v in triggered)}"
        )
    return lines


def _actions(inputs: list[Variable], tunables: list[Variable]) -> list[str]:
    what, candidates = "inputs", inputs
    if not inputs:
        what, candidates = "tunable parameters", tunables
    if not candidates:
        return [
            "# The FMU has no inputs and no tunable parameters: this experiment only observes it.",
            "# check, simulate, node, record and `evaluate zero --config <this file>` work on it;",
            "# training needs something to act on (an input or a tunable parameter).",
            "actions:",
            "  inputs: []",
            "",
        ]
    real = [v for v in candidates if v.type.startswith("Float")]
    if real:
        return _continuous(real, [v for v in candidates if v not in real], what)
    return _multi_discrete(candidates, what)


def _continuous(real: list[Variable], held: list[Variable], what: str) -> list[str]:
    lines = [
        f"actions:                        # the FMU's {what}",
        f"  inputs: [{', '.join(q(v.name) for v in real)}]",
        "  type: continuous            # the agent acts in [-1, 1], mapped onto [low, high]",
    ]
    bounds = [(v, *real_bounds(v)) for v in real]
    lines.append("  low:")
    lines += [f"    {q(v.name)}: {_num(lo)}{note or _comment(v)}" for v, lo, _, note in bounds]
    lines.append("  high:")
    lines += [f"    {q(v.name)}: {_num(hi)}{note}" for v, _, hi, note in bounds]
    return [*lines, *_held(held), ""]


def real_bounds(var: Variable) -> tuple[float, float, str]:
    """(low, high, note): the declared min/max, or a guess around the start value marked GUESS."""
    low = var.min if var.min is not None and math.isfinite(var.min) else None
    high = var.max if var.max is not None and math.isfinite(var.max) else None
    if low is not None and high is not None and low < high:
        return low, high, ""
    start = float(var.start) if isinstance(var.start, int | float) and math.isfinite(var.start) else 0.0
    half = max(abs(start) * 0.5, abs(var.nominal or 0.0), 1.0 if start == 0.0 else 0.0)
    lo = low if low is not None else start - half
    hi = high if high is not None else start + half
    if not lo < hi:
        lo, hi = (lo, lo + 2 * half) if low is not None else (hi - 2 * half, hi)
    missing = [s for s, b in (("min", low), ("max", high)) if b is None]
    return lo, hi, f"  # GUESS: the FMU declares no {'/'.join(missing) or 'usable range'}; set a real bound"


def _multi_discrete(discrete: list[Variable], what: str) -> list[str]:
    lines = [
        f"actions:                        # the FMU's {what} (whole numbers: one level per choice)",
        f"  inputs: [{', '.join(q(v.name) for v in discrete)}]",
        "  type: multi_discrete        # the agent picks one level of each",
        "  levels:",
    ]
    for v in discrete:
        levels, note = discrete_levels(v)
        lines.append(f"    {q(v.name)}: [{', '.join(str(x) for x in levels)}]{note or _comment(v)}")
    return [*lines, ""]


def discrete_levels(var: Variable) -> tuple[list[int], str]:
    """Levels of an Integer, Boolean or Enumeration variable inside its declared range or items."""
    if var.type == "Boolean":
        return [0, 1], ""
    if var.enum_items:
        return sorted({value for _, value in var.enum_items}), ""
    low, high = _TYPE_RANGES.get(var.type, (-(2**31), 2**31 - 1))
    declared = (var.min is not None, var.max is not None)
    low = int(var.min) if var.min is not None else low
    high = int(var.max) if var.max is not None else high
    if all(declared) and high - low <= 10:
        return list(range(low, high + 1)), ""
    start = int(var.start) if isinstance(var.start, int | float) else 0
    start = min(max(start, low), high)
    levels = sorted(
        {low, start, high} if all(declared) else {start, start + 1 if start < high else start - 1}
    )
    return levels, "  # GUESS: a few levels inside the declared range; list the ones you need"


def _held(held: list[Variable]) -> list[str]:
    if not held:
        return []
    lines = ["  # Held at their start values (whole-number variables do not mix with continuous actions):"]
    lines += [f"  #   {q(v.name)} ({v.type}, start {v.start})" for v in held]
    lines += [
        "  # To drive them instead: list them in inputs with type: multi_discrete and levels per input,",
        "  # or give them a time profile under scenarios.<name>.inputs.",
    ]
    return lines


def _observations(observed: list[Variable], note: str) -> list[str]:
    lines = [note] if note else []
    lines += ["observations:", f"  outputs: [{', '.join(q(v.name) for v in observed)}]"]
    lines += [f"  #   {q(v.name)}{_comment(v).replace('  #', ':')}" for v in observed]
    return [
        *lines,
        "  scale: auto                 # from the FMU's min/max or nominal; or {name: [low, high]}",
        "  history: 1                  # stack the last k samples",
        "",
    ]


def _reward_and_termination(observed: list[Variable]) -> list[str]:
    first = q(observed[0].name) if observed else '"y"'
    return [
        "reward:                        # built-in terms, an expression, or a Python callable",
        "  terms:",
        "    - alive: 1.0",
        f"    # - signal: {{name: {first}, norm: squared, weight: 1.0}}",
        "  termination_penalty: 0.0",
        "",
        "termination:",
        "  bounds: {}                  # e.g. {" + first + ": [-1.0, 1.0]}",
        "  on_fmu_terminate: true",
        "",
    ]


def _parameters(info: ModelInfo) -> list[str]:
    params = [  # an FMI 3.0 array parameter by its elements, as check and the model take it
        v
        for v in with_elements(info.variables).values()
        if v.causality == "parameter"
        and v.variability != "constant"
        and v.settable_at_init
        and not v.dimensions
    ]
    if not params:
        return [""]
    lines = [
        "  parameters: {}              # values for every episode; draw them per episode under",
        "                              # randomization.parameters. The FMU's parameters and defaults:",
    ]
    for v in params:
        value = json.dumps(v.start) if isinstance(v.start, str) else v.start
        lines.append(f"  #   {q(v.name)}: {value}{_comment(v)}")
    return [*lines, ""]
