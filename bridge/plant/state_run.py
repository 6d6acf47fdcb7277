"""``fmu-bridge state save``: run an experiment's FMU from initialisation to a time, or until it
settles, and save its state to a state file that ``model.reset_policy: {state_file: ...}`` starts
every episode from.

The run is open loop: the experiment's parameters and start values, inputs held at their start
values. "Settled" means that over the last ``window_s`` seconds no numeric output moved by more than
``tol * max(1, |y|)``, and that no continuous state would move by more than ``tol * max(1, |x|)``
over a window at its derivative now: ``|dx/dt| * window_s <= tol * max(1, |x|)``. The derivatives
are those the FMU offers: in model exchange every state's, from ``getDerivatives``
(``getContinuousStateDerivatives`` in FMI 3.0) beside ``getContinuousStates``; in co-simulation
(which has no such call) the derivative variables the model description's ``<Derivatives>`` lists,
read by value reference with their states; where it lists none (or the FMU refuses to read them),
the outputs alone. The run gives up at ``max_time_s`` with an error saying how far it got.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bridge.errors import BridgeError, ConfigError, StateFileError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, timing
from bridge.fmu import Model, read_model_info, state_file
from bridge.fmu.state_file import StateHeader
from bridge.fmu.states import derivative_pairs
from bridge.plant.experiment_model import experiment_model


@dataclass(frozen=True)
class SavedRun:
    """What ``save_state`` wrote: the file, its header, and for ``steady`` the change measured over
    the last window (largest over the outputs, relative to ``max(1, |y|)``)."""

    path: Path
    header: StateHeader
    outputs: dict[str, float]
    change: float | None = None
    derivatives: str = ""  # what --steady watched besides the outputs ("" for --until)


def save_state(
    experiment: Experiment,
    output: Path,
    *,
    until_s: float | None = None,
    steady: bool = False,
    tol: float = 1e-6,
    window_s: float = 1.0,
    max_time_s: float = 1e4,
) -> SavedRun:
    """Initialise the experiment's FMU, run it to ``until_s`` (simulation time) or to a steady state,
    and write its state to ``output``; :class:`StateFileError` where the FMU cannot serialise."""
    if until_s is not None and steady:
        raise ConfigError("state save: give either a time to run to (--until) or --steady, not both")
    if until_s is None and not steady:
        raise ConfigError("state save: say when to save: --until T (simulation time, s) or --steady")
    fmu_path = resolve_fmu(experiment)
    info = check_experiment(experiment, read_model_info(fmu_path))
    t = timing(experiment, info)
    with experiment_model(experiment, fmu_path, t, from_state_file=False) as model:
        why = model.serialize_refusal
        if why is not None:
            raise StateFileError(f"{why} [{fmu_path}]")
        m = experiment.model
        model.initialize({**m.parameters, **m.start_values})
        names = _outputs(model)
        change, watched = None, ""
        if until_s is not None:
            steps = _steps_to(model, until_s)
            if steps > 0:
                model.advance(steps)
        else:
            slopes = _Derivatives(model)
            watched = slopes.what
            change = _run_to_steady(model, names, slopes, tol=tol, window_s=window_s, max_time_s=max_time_s)
        saved = model.state_file()
        state_file.write(output, saved)
        values = {n: float(v) for n, v in model.get(names).items()}
    return SavedRun(Path(output), saved.header, values, change, watched)


def _outputs(model: Model) -> list[str]:
    numeric = ("Float64", "Float32", "Real")
    return [
        v.name
        for v in model.info.variables.values()
        if v.causality == "output" and v.type in numeric and not v.is_array
    ]


def _steps_to(model: Model, until_s: float) -> int:
    steps = (until_s - model.start_time_s) / model.step_size_s
    if math.isfinite(steps) and steps < 0:
        raise ConfigError(
            f"--until {until_s:g} s is before the FMU's start time {model.start_time_s:g} s; give a time at "
            f"or after the start"
        )
    k = round(steps) if math.isfinite(steps) else 0
    if not math.isfinite(steps) or abs(steps - k) > 1e-9 * max(1.0, abs(steps)):
        raise ConfigError(
            f"--until {until_s:g} s is not on the FMU's time grid (start {model.start_time_s:g} s, step "
            f"{model.step_size_s:g} s); give a whole number of steps after the start"
        )
    return k


class _Derivatives:
    """The continuous states' derivatives the FMU offers (see the module's text), as the relative
    move ``|dx/dt| * window / max(1, |x|)`` they would make over a window."""

    def __init__(self, model: Model) -> None:
        self.model, self.pairs = model, []
        if model.interface == "me":
            n = model.info.number_of_states
            self.what = f"{n} state derivatives (model exchange)" if n else ""
            return
        try:
            pairs = derivative_pairs(model)
            if pairs:
                model.get([name for pair in pairs for name in pair])  # readable at all?
        except BridgeError:
            pairs = []
        self.pairs = pairs
        self.what = ", ".join(d for d, _ in pairs)

    def move(self, window_s: float) -> float:
        if not self.what:
            return 0.0
        if self.model.interface == "me":
            dx, x = self.model.derivatives(), self.model.continuous_states()
        else:
            values = self.model.get([name for pair in self.pairs for name in pair])
            dx = np.array([float(values[d]) for d, _ in self.pairs])
            x = np.array([float(values[s]) for _, s in self.pairs])
        return float(np.max(np.abs(dx) * window_s / np.maximum(1.0, np.abs(x))))


def _run_to_steady(
    model: Model, names: list[str], slopes: _Derivatives, *, tol: float, window_s: float, max_time_s: float
) -> float:
    if not names and not slopes.what:
        raise ConfigError(
            f"--steady: {model.info.model_name} has no numeric outputs or state derivatives to watch; "
            "use --until"
        )
    window = max(1, round(window_s / model.step_size_s))
    limit = math.ceil(max_time_s / model.step_size_s)
    before = _values(model, names)
    change = math.inf
    while model.step_index + window <= limit:
        stopped = model.advance(window)
        now = _values(model, names)
        moved = float(np.max(np.abs(now - before) / np.maximum(1.0, np.abs(now)))) if names else 0.0
        change = max(moved, slopes.move(model.step_size_s * window))
        if change <= tol:
            return change
        if stopped:
            break  # the FMU asked to stop before it settled
        before = now
    raise StateFileError(
        f"{model.info.model_name} did not settle by t = {model.time_s:g} s (--max-time {max_time_s:g}): "
        f"the outputs moved (or the states would move at their derivatives) by "
        f"{change:.3g} (relative) over the last {window_s:g} s, more than --tol {tol:g}; raise "
        f"--max-time or --tol, or save at a time with --until"
    )


def _values(model: Model, names: list[str]) -> np.ndarray:
    return np.array([float(v) for v in model.get(names).values()])
