"""Checks of an experiment against its FMU: names exist, causality fits the role, steps divide.

These run before any episode, so a typo in a YAML file fails in milliseconds with the key,
the bad value, what is allowed, and the file, instead of deep inside training.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from bridge.errors import ConfigError
from bridge.experiment.config import (
    MAX_SAMPLES,
    Experiment,
    known_references,
    sampling_ratio,
    scenario_inputs,
)
from bridge.fmu import structure
from bridge.fmu.vocab import ModelInfo, Variable


def resolve_fmu(experiment: Experiment) -> Path:
    """The FMU of ``model.fmu``: a path (relative to the experiment file) or ``example:NAME[:VER][:IF]``."""
    spec = experiment.model.fmu
    if not spec or spec.lower().endswith((".ssp", ".ssd")):
        raise ConfigError(
            f"model.fmu: this experiment is a system of FMUs, not one FMU; use `fmu-bridge system ...` "
            f"or bridge.env.plants.plant_for(experiment) [{experiment.source}]"
        )
    if spec.startswith("example:"):
        from bridge.models import example_fmu

        parts = spec.split(":")[1:]
        name = parts[0]
        version = parts[1] if len(parts) > 1 and parts[1] else "2.0"
        interface = parts[2] if len(parts) > 2 else ("me" if experiment.model.interface == "me" else "cs")
        return example_fmu(name, version, interface)
    path = Path(spec).expanduser()
    if not path.is_absolute():
        path = experiment.base_dir / path
    if not path.exists():
        raise ConfigError(
            f"model.fmu: {spec!r} does not exist (looked at {path}); give a path relative to the "
            f"experiment file or example:NAME [{experiment.source}]"
        )
    return path


def resolve_state_file(experiment: Experiment) -> Path | None:
    """The file of ``model.reset_policy: {state_file: PATH}`` (relative to the experiment file), or None."""
    policy = experiment.model.reset_policy
    if isinstance(policy, str):
        return None
    path = Path(policy.state_file).expanduser()
    if not path.is_absolute():
        path = experiment.base_dir / path
    if not path.is_file():
        raise ConfigError(
            f"model.reset_policy.state_file: {policy.state_file!r} does not exist (looked at {path}); save "
            f"one with `fmu-bridge state save` or give a path relative to the experiment file "
            f"[{experiment.source}]"
        )
    return path


@dataclass(frozen=True)
class Timing:
    step_size_s: float
    steps_per_sample: int
    sampling_time_s: float
    start_time_s: float


def timing(experiment: Experiment, info: ModelInfo) -> Timing:
    model = experiment.model
    h = model.step_size or info.default_experiment.step_size_s
    if h is None:
        raise ConfigError(
            f"model.step_size: {info.model_name} declares no default step size; set model.step_size "
            f"(seconds) [{experiment.source}]"
        )
    ts = model.sampling_time or h
    try:
        n = sampling_ratio(ts, h)
    except ConfigError as exc:
        raise ConfigError(f"{exc} [{experiment.source}]") from None
    _check_episode_lengths(experiment, n * h)
    return Timing(step_size_s=h, steps_per_sample=n, sampling_time_s=n * h, start_time_s=model.start_time)


def _check_episode_lengths(experiment: Experiment, sampling_time_s: float) -> None:
    """The sample limit of the config, also where the sampling time comes from the FMU."""
    durations = {"model.episode_duration": experiment.model.episode_duration}
    for name, sc in experiment.scenarios.items():
        if sc.episode_duration is not None:
            durations[f"scenarios.{name}.episode_duration"] = sc.episode_duration
    for key, duration_s in durations.items():
        samples = duration_s / sampling_time_s
        if samples < 1 - 1e-9:
            raise ConfigError(
                f"{key}: {duration_s:g} s is shorter than one sample ({sampling_time_s:g} s): an episode "
                f"needs at least one; lengthen the episode or sample more often [{experiment.source}]"
            )
        if samples > MAX_SAMPLES:
            raise ConfigError(
                f"{key}: {duration_s:g} s at {sampling_time_s:g} s per sample is {samples:.3g} samples; "
                f"at most {MAX_SAMPLES:.0e} per episode are allowed (profiles are precomputed per "
                f"sample): shorten the episode or sample less often [{experiment.source}]"
            )


def check_experiment(experiment: Experiment, info: ModelInfo) -> ModelInfo:
    """Check every name and role in ``experiment`` against the model ``info``; returns ``info``
    with the array sizes the experiment's structural parameters give (``model.structural_parameters``)."""
    where = f" [{experiment.source}]" if experiment.source else ""
    info = configured(experiment, info)
    variables = with_elements(info.variables)
    timing(experiment, info)
    _check_values(experiment, variables, where)
    _check_actions(experiment, variables, where)
    _check_observations(experiment, variables, where)
    signals = set(variables) | known_references(experiment)
    _check_reward_and_termination(experiment, variables, signals, where)
    _check_evaluation(experiment, signals, where)
    _check_clocks(experiment, info, where)
    return info


def _check_clocks(experiment: Experiment, info: ModelInfo, where: str) -> None:
    m = experiment.model
    if not (m.clock_intervals or m.clock_schedule):
        return
    from bridge.fmu.clock_rules import check_settings

    try:
        check_settings(info, m.interface, m.clock_intervals, m.clock_schedule)
    except ConfigError as exc:
        raise ConfigError(f"model: {exc}{where}") from None


def configured(experiment: Experiment, info: ModelInfo) -> ModelInfo:
    """``info`` with the array sizes ``model.structural_parameters`` set (where there are any)."""
    values = experiment.model.structural_parameters
    if not values:
        return info
    checked = structure.check(info, values, "model.structural_parameters")
    return structure.resized(info, structure.sizes_of(checked))


def with_elements(variables: Mapping[str, Variable]) -> dict[str, Variable]:
    """``variables`` plus one scalar entry per element of each FMI 3.0 array (``y[2,3]``, 1-based).

    Configs name array elements, never whole arrays: an element is a scalar signal everywhere
    (actions, observations, rewards, bounds), so the task and these checks treat it as one.
    """
    out = dict(variables)
    for var in variables.values():
        if not var.dimensions:
            continue
        starts = var.element_starts()
        for i, name in enumerate(var.element_names()):
            out.setdefault(
                name, dataclasses.replace(var, name=name, start=starts[i], dimensions=(), is_array=False)
            )
    return out


def _unknown(
    key: str,
    name: str,
    names: Iterable[str],
    where: str,
    what: str = "a variable of the FMU",
    *,
    note: str = "",
) -> ConfigError:
    names = sorted(names)
    close = difflib.get_close_matches(name, names, n=4, cutoff=0.5)
    hint = (
        f"did you mean {close}?" if close else f"{len(names)} are available; `fmu-bridge inspect` lists them"
    )
    return ConfigError(f"{key}: {name!r} is not {what}{note}; {hint}{where}")


def _array_note(name: str, variables: Mapping[str, Variable]) -> str:
    """For an element of an array that has no such element: the array's shape, and what sizes it."""
    base = name.split("[", 1)[0] if name.endswith("]") else ""
    var = variables.get(base) if base else None
    if var is None or not var.dimensions:
        return ""
    shape = ",".join(map(str, var.dimensions))
    sized = any(vr is not None for vr in var.dimension_vrs)
    why = ", sized by model.structural_parameters or, without it, the structural parameters' start values"
    return f" ({base} is {var.type}[{shape}] here{why if sized else ''})"


def _need(key: str, name: str, variables: Mapping[str, Variable], where: str) -> Variable:
    if name not in variables:
        raise _unknown(key, name, variables, where, note=_array_note(name, variables))
    var = variables[name]
    if var.dimensions:
        shape = ",".join(map(str, var.dimensions))
        elements = var.element_names()
        shown = ", ".join(elements[:3]) + (f", ... {elements[-1]}" if len(elements) > 3 else "")
        raise ConfigError(
            f"{key}: {name!r} is an FMI 3.0 array {var.type}[{shape}]; configs name its elements one by "
            f"one (1-based, row-major): {shown}{where}"
        )
    return var


def _check_values(exp: Experiment, variables: Mapping[str, Variable], where: str) -> None:
    sections: list[tuple[str, Iterable[str]]] = [
        ("model.parameters", exp.model.parameters),
        ("model.start_values", exp.model.start_values),
        ("randomization.parameters", exp.randomization.parameters),
        ("randomization.start_values", exp.randomization.start_values),
    ]
    for name, sc in exp.scenarios.items():
        sections += [
            (f"scenarios.{name}.parameters", sc.parameters),
            (f"scenarios.{name}.start_values", sc.start_values),
            (f"scenarios.{name}.randomization.parameters", sc.randomization.parameters),
            (f"scenarios.{name}.randomization.start_values", sc.randomization.start_values),
        ]
    for key, names in sections:
        for var_name in names:
            var = _need(key, var_name, variables, where)
            if var.causality == "structuralParameter":
                raise ConfigError(
                    f"{key}: {var_name!r} is a structural parameter (an array size): it is set in FMI 3.0 "
                    f"configuration mode once per instance, not per episode; give it under "
                    f"model.structural_parameters{where}"
                )
            if not var.settable_at_init:
                raise ConfigError(
                    f"{key}: {var_name!r} is a {var.variability} {var.causality} and cannot be set; "
                    f"only parameters, inputs and variables with initial exact/approx can{where}"
                )
    for name, sc in exp.scenarios.items():
        for var_name in sc.inputs:
            var = _need(f"scenarios.{name}.inputs", var_name, variables, where)
            if var.causality != "input":
                raise ConfigError(
                    f"scenarios.{name}.inputs: {var_name!r} is a {var.causality}, not an input of the FMU; "
                    f"time profiles drive inputs (use parameters for constants){where}"
                )
            if var_name in exp.actions.inputs:
                raise ConfigError(
                    f"scenarios.{name}.inputs: {var_name!r} is driven by the agent (actions.inputs); "
                    f"a profile cannot drive it too{where}"
                )


def _check_actions(exp: Experiment, variables: Mapping[str, Variable], where: str) -> None:
    actions = exp.actions
    for name in actions.inputs:
        var = _need("actions.inputs", name, variables, where)
        if not var.settable_in_step:
            drivable = [v.name for v in variables.values() if v.settable_in_step and not v.dimensions]
            raise ConfigError(
                f"actions.inputs: {name!r} has causality {var.causality!r} in the FMU, not 'input' "
                f"({var.variability}); the agent drives inputs and tunable parameters only "
                f"({drivable or 'this FMU has none'}){where}"
            )
        triggered = var.clock is not None and var.clock.interval_variability == "triggered"
        if not var.is_numeric and not triggered:
            raise ConfigError(
                f"actions.inputs: {name!r} is a {var.type} input; actions are numeric, or FMI 3.0 "
                f"triggered input clocks (ticked when the action is above 0.5){where}"
            )
        if actions.type == "continuous":
            low, high = action_bounds(exp, var)
            for side, bound, key in (("low", low, "actions.low"), ("high", high, "actions.high")):
                if bound is None or not math.isfinite(bound):
                    raise ConfigError(
                        f"{key}.{name}: the {side} bound is {bound}; continuous actions need finite bounds "
                        f"(the FMU declares min={var.min}, max={var.max}): set {key}.{name}{where}"
                    )
            if not low < high:  # type: ignore[operator]
                raise ConfigError(f"actions: bounds of {name!r} need low < high, got [{low}, {high}]{where}")
    for name in exp.noise.actions:
        if name not in actions.inputs:
            raise _unknown("noise.actions", name, actions.inputs, where, "an action input")


def action_bounds(exp: Experiment, var: Variable) -> tuple[float | None, float | None]:
    """An action's bounds: the experiment's, else the FMU's min/max ([0, 1] for a triggered clock)."""
    low, high = (0.0, 1.0) if var.type == "Clock" else (var.min, var.max)
    return exp.actions.low.get(var.name, low), exp.actions.high.get(var.name, high)


def _check_observations(exp: Experiment, variables: Mapping[str, Variable], where: str) -> None:
    obs = exp.observations
    for name in [*obs.outputs, *obs.errors.values()]:
        var = _need("observations.outputs", name, variables, where)
        if var.causality == "input":
            raise ConfigError(
                f"observations.outputs: {name!r} is an input of the FMU; FMUs do not report inputs as "
                f"measurements: observe an output, or set observations.include_action: true{where}"
            )
        if not var.is_numeric:
            raise ConfigError(
                f"observations.outputs: {name!r} is a {var.type} variable; observations are numeric{where}"
            )
    references = known_references(exp)
    for name in [*obs.references, *obs.errors]:
        if name not in references:
            raise _unknown(
                "observations.references",
                name,
                references,
                where,
                "a reference defined by a scenario or randomization.references",
            )
        _every_scenario_defines(exp, name, where)
    for name in exp.noise.observations:
        if name not in obs.outputs:
            raise _unknown("noise.observations", name, obs.outputs, where, "an observed output")
    if isinstance(obs.scale, dict):
        known = set(obs.outputs) | set(obs.references) | set(obs.errors.values())
        for name in obs.scale:
            if name not in known:
                raise _unknown("observations.scale", name, known, where, "an observed signal")


def _every_scenario_defines(exp: Experiment, reference: str, where: str) -> None:
    if reference in exp.randomization.references:
        return
    missing = [
        n
        for n, sc in exp.scenarios.items()
        if reference not in sc.references and reference not in sc.randomization.references
    ]
    if missing or not exp.scenarios:
        raise ConfigError(
            f"reference {reference!r} is used but scenarios {missing or ['(none defined)']} do not define "
            f"it; give every scenario a references.{reference} profile or draw it in "
            f"randomization.references{where}"
        )


def _check_reward_and_termination(
    exp: Experiment, variables: Mapping[str, Variable], signals: set[str], where: str
) -> None:
    for i, term in enumerate(exp.reward.terms):
        key = f"reward.terms[{i}]"
        if term.tracking is not None:
            _need(f"{key}.tracking.output", term.tracking.output, variables, where)
            if term.tracking.reference not in known_references(exp):
                raise _unknown(
                    f"{key}.tracking.reference",
                    term.tracking.reference,
                    known_references(exp),
                    where,
                    "a reference defined by the scenarios",
                )
            _every_scenario_defines(exp, term.tracking.reference, where)
        for kind in ("effort", "rate"):
            spec = getattr(term, kind)
            if spec is not None and spec.name not in exp.actions.inputs:
                raise _unknown(f"{key}.{kind}.name", spec.name, exp.actions.inputs, where, "an action input")
        if term.signal is not None and term.signal.name not in signals:
            raise _unknown(f"{key}.signal.name", term.signal.name, signals, where, "a signal")
    for name in exp.termination.bounds:
        if name not in signals:
            raise _unknown("termination.bounds", name, signals, where, "a signal (FMU variable or reference)")
    extra_inputs = [n for n in scenario_inputs(exp) if n not in variables]
    if extra_inputs:
        raise _unknown("scenarios.inputs", extra_inputs[0], variables, where)


def _check_evaluation(exp: Experiment, signals: set[str], where: str) -> None:
    """Names in ``evaluation.metrics`` and ``evaluation.baselines`` are signals and action inputs."""
    metrics, inputs = exp.evaluation.metrics, exp.actions.inputs
    for i, pair in enumerate(metrics.tracking):
        for part, name in zip(("output", "reference"), pair):
            if name not in signals:
                raise _unknown(f"evaluation.metrics.tracking[{i}] ({part})", name, signals, where, "a signal")
    for name in metrics.effort or []:
        if name not in inputs:
            raise _unknown("evaluation.metrics.effort", name, inputs, where, "an action input")
    for name in metrics.constraints:
        if name not in signals:
            raise _unknown("evaluation.metrics.constraints", name, signals, where, "a signal")
    for base_name, base in exp.evaluation.baselines.items():
        key = f"evaluation.baselines.{base_name}"
        for part in ("output", "reference"):
            name = getattr(base, part)
            if name is not None and name not in signals:
                raise _unknown(f"{key}.{part}", name, signals, where, "a signal")
        if base.input is not None and base.input not in inputs:
            raise _unknown(f"{key}.input", base.input, inputs, where, "an action input")
