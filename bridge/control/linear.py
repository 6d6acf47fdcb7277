"""Linear models of an FMU around an operating point, and their sampled (zero-order hold) form.

``linearize`` opens the FMU's model-exchange interface, sets the continuous states and the inputs
of the operating point, and takes central finite differences of the state derivatives and of the
chosen outputs (FMI's ``SetContinuousStates`` / ``GetDerivatives``), so

    dx/dt ~ f0 + A (x - x0) + B (u - u0),   y ~ y0 + C (x - x0) + D (u - u0).

Co-simulation alone cannot be linearised this way: FMI does not let a co-simulation master set
the states, so the FMU must offer model exchange (every example model with states does).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bridge.control.deps import require
from bridge.errors import ConfigError
from bridge.fmu.model import Model
from bridge.fmu.states import state_names

Matrix = NDArray[np.float64]


@dataclass(frozen=True)
class LinearModel:
    """x' = f0 + A dx + B du (continuous, ``dt`` None) or x+ = x0 + f0 + A dx + B du (sampled),
    y = y0 + C dx + D du, with dx = x - x0 and du = u - u0."""

    a: Matrix
    b: Matrix
    c: Matrix
    d: Matrix
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    x0: Matrix
    u0: Matrix
    y0: Matrix
    f0: Matrix
    nominal: Matrix
    dt: float | None = None

    def columns(self, names: Sequence[str]) -> tuple[Matrix, Matrix]:
        """The columns of B and D for some of the inputs."""
        index = [self.inputs.index(n) for n in names]
        return self.b[:, index], self.d[:, index]

    def rows(self, names: Sequence[str]) -> tuple[Matrix, Matrix]:
        """The rows of C and D for some of the outputs."""
        index = [self.outputs.index(n) for n in names]
        return self.c[index], self.d[index]

    def discretize(self, dt: float) -> LinearModel:
        """Zero-order hold over ``dt`` (the matrix exponential of the augmented system)."""
        if self.dt is not None:
            raise ConfigError(f"this model is sampled already (dt = {self.dt} s)")
        expm = require("scipy.linalg", "sampling a linearised model (lqr and mpc baselines)").expm
        n, m = self.b.shape
        block = np.zeros((n + m + 1, n + m + 1))
        block[:n, :n], block[:n, n : n + m], block[:n, -1] = self.a, self.b, self.f0
        phi = expm(block * dt)
        return replace(self, a=phi[:n, :n], b=phi[:n, n : n + m], f0=phi[:n, -1], dt=dt)


def linearize(
    fmu: str | Path,
    *,
    inputs: Sequence[str],
    outputs: Sequence[str] = (),
    states: Sequence[str] | None = None,
    operating_point: Mapping[str, float] | None = None,
    relative_step: float = 1e-6,
) -> LinearModel:
    """The continuous linear model of ``fmu`` (model exchange) at ``operating_point``.

    Args:
        inputs: FMU inputs to differentiate by (the controlled ones and any disturbances).
        outputs: FMU variables to differentiate (C, D); states may be outputs too.
        states: the states to keep (default all); the others stay at their operating value.
        operating_point: values of states, inputs and parameters (the rest keep their start values).
        relative_step: central differences of ``relative_step * max(|value|, nominal)``.
    """
    point = dict(operating_point or {})
    try:
        opened = Model(fmu, interface="me")
    except ConfigError as exc:
        raise ConfigError(
            f"linearisation sets the FMU's continuous states, which needs model exchange (FMI does not "
            f"let a co-simulation master set states); export the FMU with model exchange too ({exc})"
        ) from exc
    with opened as model:
        every = state_names(model)
        chosen = list(states) if states is not None else every
        unknown = [s for s in chosen if s not in every]
        if unknown:
            raise ConfigError(
                f"states {unknown} are not continuous states of {model.info.model_name}: {every}"
            )
        for name in [*inputs, *outputs]:
            model.variable(name)  # a clear error for a name the FMU does not have
        state_values = {k: v for k, v in point.items() if k in every}
        settings = {k: v for k, v in point.items() if k not in every and k not in inputs}
        model.initialize(settings)
        x_all = model.continuous_states()
        for name, value in state_values.items():
            x_all[every.index(name)] = value
        base_x = x_all.copy()
        u0 = np.array([point.get(n, float(model.get([n])[n])) for n in inputs])
        index = [every.index(s) for s in chosen]

        def evaluate(x: Matrix, u: Matrix) -> tuple[Matrix, Matrix]:
            model.set_continuous_states(x)
            model.set(dict(zip(inputs, (float(v) for v in u))))
            dx_all = model.derivatives()
            values = model.get(outputs) if outputs else {}
            return dx_all[index].copy(), np.array([float(values[o]) for o in outputs])

        f0, y0 = evaluate(base_x, u0)
        nominal_x = np.array([_nominal(model, s) for s in chosen])
        nominal_u = np.array([_nominal(model, u) for u in inputs])
        a, c = _central(lambda x: evaluate(x, u0), base_x, index, nominal_x, relative_step)
        b, d = _central(lambda u: evaluate(base_x, u), u0, range(len(inputs)), nominal_u, relative_step)
    return LinearModel(
        a=a, b=b, c=c, d=d, states=tuple(chosen), inputs=tuple(inputs), outputs=tuple(outputs),
        x0=base_x[index], u0=u0, y0=y0, f0=f0, nominal=nominal_x,
    )  # fmt: skip


def _central(
    fn: Callable[[Matrix], tuple[Matrix, Matrix]],
    base: Matrix,
    positions: Iterable[int],
    nominal: Matrix,
    relative_step: float,
) -> tuple[Matrix, Matrix]:
    """Central differences of both results of ``fn`` by the entries ``positions`` of ``base``."""
    f_cols, y_cols = [], []
    for j, i in enumerate(positions):
        h = relative_step * max(abs(base[i]), nominal[j])
        plus, minus = base.copy(), base.copy()
        plus[i] += h
        minus[i] -= h
        (fp, yp), (fm, ym) = fn(plus), fn(minus)
        f_cols.append((fp - fm) / (2 * h))
        y_cols.append((yp - ym) / (2 * h))
    return np.column_stack(f_cols), np.column_stack(y_cols)


def _nominal(model: Model, name: str) -> float:
    nominal = getattr(model.variable(name), "nominal", None)
    return float(nominal) if nominal and np.isfinite(nominal) and nominal > 0 else 1.0
