"""The LQR and MPC controllers at run time: estimator, targets, preview, feedback.

Both see the task's named signals in physical units (as the PID baseline does) and return the
physical values of their inputs. Designs are made once per controller from the FMU's model
exchange interface (one per schedule point, blended linearly on the schedule signal).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bridge.control.design import PointDesign, blend, design_point, preview_samples
from bridge.control.linear import Matrix
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.experiment.control import ControlDesign


def linearisation_fmu(experiment: Experiment) -> Path:
    """The model-exchange FMU of the experiment's model (a bundled example is built as one)."""
    spec = experiment.model.fmu
    if spec.startswith("example:"):
        from bridge.models import example_fmu

        parts = spec.split(":")[1:]
        version = parts[1] if len(parts) > 1 and parts[1] else "2.0"
        return example_fmu(parts[0], version, "me")
    from bridge.experiment.validate import resolve_fmu

    return resolve_fmu(experiment)


def noise_std(experiment: Experiment) -> dict[str, float]:
    """Standard deviations of the experiment's normal sensor noise, per signal."""
    return {name: float(d.normal[1]) for name, d in experiment.noise.observations.items() if d.normal}


@dataclass
class _Blended:
    k: Matrix
    preview: Matrix
    target: Matrix
    kalman: Matrix
    a: Matrix
    bu: Matrix
    bw: Matrix
    f0: Matrix
    cm: Matrix
    dm: Matrix
    dmw: Matrix
    x0: Matrix
    u0: Matrix
    w0: Matrix
    ym0: Matrix
    yt0: Matrix


class LinearController:
    """LQR with preview feed-forward and a Kalman filter; ``Mpc`` replaces the feedback law."""

    kind = "lqr"

    def __init__(self, design: ControlDesign, experiment: Experiment, dt: float, name: str = "lqr") -> None:
        self.spec, self.name, self.dt = design, name, dt
        self._experiment = experiment
        self.designs: list[PointDesign] = []
        self.points: list[float] = []
        self._limits: list[tuple[float, float]] = []

    # -- design --------------------------------------------------------------------------------
    def build(self, limits: Mapping[str, tuple[float, float]] | None = None) -> None:
        """Linearise and design (once); ``limits`` per input where the design gives none."""
        if not self.designs:
            fmu, noise = linearisation_fmu(self._experiment), noise_std(self._experiment)
            noise.update(self.spec.measurement_noise)
            schedule = self.spec.schedule
            if schedule is None:
                self.designs = [design_point(fmu, self.spec, self.dt, noise)]
                self.points = [0.0]
            else:
                self.points = list(schedule.points)
                self.designs = [
                    design_point(fmu, self.spec, self.dt, noise, {schedule.input: v}) for v in self.points
                ]
        if self.spec.output_limits and self.kind != "mpc":
            raise ConfigError(
                f"baseline {self.name}: design.output_limits {sorted(self.spec.output_limits)} need a "
                "controller that plans ahead: use type: mpc (an lqr cannot keep outputs within limits)"
            )
        given = {**(limits or {}), **self.spec.limits}
        self._limits = [given.get(name, (-np.inf, np.inf)) for name in self.spec.inputs]
        self._rate = np.array([self.spec.rate_limits.get(name, np.inf) for name in self.spec.inputs])
        self._steps = preview_samples(self.spec, self.dt)

    def check_signals(self, signal_names: tuple[str, ...] | list[str]) -> None:
        s = self.spec
        needed = [*s.measured, *s.tracking.values(), *s.tracking, *s.disturbances.values()]
        needed += [sig for table in s.preview.values() for sig in table.values()]
        needed += [s.schedule.signal] if s.schedule else []
        missing = sorted({n for n in needed if n not in signal_names})
        if missing:
            raise ConfigError(
                f"baseline {self.name}: {missing} are not signals of the task; signals: {list(signal_names)} "
                "(observe an FMU output under observations.outputs to make it a signal)"
            )

    # -- run time ------------------------------------------------------------------------------
    def reset(self) -> None:
        n = len(self.designs[0].model.states)
        self._x = np.zeros(n)  # predicted state deviation
        self._z = np.zeros(len(self.spec.integral))
        self._u_prev: Matrix | None = None
        self.rate_limited = 0  # samples of this episode whose command the rate limit held back

    def _at(self, signals: Mapping[str, float]) -> _Blended:
        value = signals[self.spec.schedule.signal] if self.spec.schedule else 0.0
        lo, hi, t = blend(self.designs, self.points, value)
        self._blend = (lo, hi, t)  # the mpc blends its two neighbouring plans the same way
        d0, d1 = self.designs[lo], self.designs[hi]

        def mix(get: Any) -> Matrix:
            a, b = get(d0), get(d1)
            return a if t == 0.0 else (1 - t) * a + t * b  # type: ignore[no-any-return]

        nu = len(self.spec.inputs)
        mi = [d0.model.outputs.index(o) for o in self.spec.measured]
        ti = [d0.model.outputs.index(o) for o in self.spec.tracking]
        return _Blended(
            k=mix(lambda d: d.k), preview=mix(lambda d: d.preview), target=mix(lambda d: d.target),
            kalman=mix(lambda d: d.kalman), a=mix(lambda d: d.model.a),
            bu=mix(lambda d: d.model.b[:, :nu]), bw=mix(lambda d: d.bw), f0=mix(lambda d: d.model.f0),
            cm=mix(lambda d: d.cm), dm=mix(lambda d: d.dm), dmw=mix(lambda d: d.dmw),
            x0=mix(lambda d: d.model.x0), u0=mix(lambda d: d.model.u0[:nu]),
            w0=mix(lambda d: d.model.u0[nu:]),
            ym0=mix(lambda d: d.model.y0[mi]), yt0=mix(lambda d: d.model.y0[ti]),
        )  # fmt: skip

    def _disturbance_sequence(self, signals: Mapping[str, float], steps: int) -> Matrix:
        """Each disturbance now and ``steps`` samples ahead (linear between previews, then held)."""
        out = np.zeros((steps + 1, len(self.spec.disturbances)))
        times = np.arange(steps + 1) * self.dt
        for i, (name, signal) in enumerate(self.spec.disturbances.items()):
            table = sorted(self.spec.preview.get(name, {}).items())
            known_t = [0.0, *(t for t, _ in table)]
            known_v = [signals[signal], *(signals[s] for _, s in table)]
            out[:, i] = np.interp(times, known_t, known_v)
        return out

    def control(self, signals: Mapping[str, float]) -> list[float]:
        """Physical values of ``design.inputs`` for this sample."""
        s = self.spec
        m = self._at(signals)
        steps = max(self._steps, self.horizon_samples())
        w = self._disturbance_sequence(signals, steps) - m.w0
        u_prev = m.u0 if self._u_prev is None else self._u_prev
        # estimator: correct the prediction with the measurement
        y = np.array([signals[name] for name in s.measured]) - m.ym0
        innovation = y - m.cm @ self._x - m.dm @ (u_prev - m.u0) - m.dmw @ w[0]
        x_hat = self._x + m.kalman @ innovation
        # targets along the preview
        refs = np.array([signals[ref] for ref in s.tracking.values()]) - m.yt0
        columns = np.hstack([w, np.tile(refs, (len(w), 1)), np.ones((len(w), 1))])
        targets = columns @ m.target.T  # (steps + 1, n + m)
        n = len(x_hat)
        x_star, u_star = targets[:, :n], targets[:, n:]
        state = np.concatenate([x_hat - x_star[0], self._z])
        nu = self._law(m, state, x_star, u_star, u_prev, w=w)
        u = m.u0 + u_star[0] + nu
        low = np.array([lo for lo, _ in self._limits])
        high = np.array([hi for _, hi in self._limits])
        step = self._rate * self.dt  # the actuator's rate limit, for every design (the mpc plans with it)
        limited = np.clip(u, u_prev - step, u_prev + step)
        self.rate_limited += int(np.any(np.abs(limited - u) > 1e-9 * np.maximum(1.0, np.abs(u))))
        applied = np.clip(limited, low, high)
        span = 1e-6 * np.maximum(1.0, np.abs(applied))
        saturated = np.any((applied <= low + span) | (applied >= high - span))
        if len(self._z) and not saturated:  # integrate only while no input is at a limit (anti-windup)
            tracked = [o for o in s.tracking if o in s.integral]
            self._z = self._z + self.dt * np.array([signals[s.tracking[o]] - signals[o] for o in tracked])
        self._x = m.a @ x_hat + m.bu @ (applied - m.u0) + m.bw @ w[0] + m.f0
        self._u_prev = applied
        return [float(v) for v in applied]

    def horizon_samples(self) -> int:
        return 0

    @property
    def failures(self) -> int:
        """Samples where an optimiser gave no answer (none here: the LQR law is closed form)."""
        return 0

    def _law(
        self, m: _Blended, state: Matrix, x_star: Matrix, u_star: Matrix, u_prev: Matrix, *, w: Matrix
    ) -> Matrix:
        """nu = -K s - sum_j F_j (x*_j - x*_j+1) (``w``, the disturbances ahead, serves the mpc)."""
        j = min(len(x_star) - 1, len(m.preview))
        changes = x_star[:j] - x_star[1 : j + 1]
        feedforward = np.einsum("jmn,jn->m", m.preview[:j], changes) if j else 0.0
        return -m.k @ state - feedforward
