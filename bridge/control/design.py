"""LQR design on the sampled linear model: targets, feedback, preview feed-forward and estimator.

For a disturbance w (FMU inputs such as the path curvature) and references r of tracked outputs,
the steady-state target (x*, u*) solves x* = A x* + B u* + E w + f0 and C_t x* + D_t u* = r. The
errors xi = x - x* and nu = u - u* follow xi+ = A xi + B nu + (x*_k - x*_k+1): a target that moves
with the previewed disturbance is a known input. With the stabilising Riccati solution P of the
error system (integrals of the tracking errors appended when asked), the optimal law is

    nu_k = -K s_k - (R + B'PB)^-1 B' sum_j (A - BK)'^j P d_k+j,   d_j = x*_j - x*_j+1,

feedback plus a feed-forward of the previewed target changes. A steady-state Kalman filter
estimates the states the task does not measure (and filters the sensor noise).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bridge.control.linear import LinearModel, Matrix, linearize
from bridge.control.riccati import dare
from bridge.errors import ConfigError
from bridge.experiment.control import ControlDesign


@dataclass(frozen=True)
class PointDesign:
    """Everything the controller needs at one operating point (deviation coordinates)."""

    model: LinearModel  # sampled
    a: Matrix  # augmented error system (states, then integrals)
    b: Matrix
    q: Matrix
    r: Matrix
    k: Matrix
    p: Matrix
    preview: Matrix  # (n_preview + 1, m, n): F_j with nu_ff = -sum_j F_j d_j
    target: Matrix  # (n + m, p + t + 1): [x*; u*] = target @ [dw; r - y0_t; 1]
    kalman: Matrix  # filter gain L (n, measured)
    bw: Matrix
    cm: Matrix
    dm: Matrix  # measured outputs' feedthrough of the controlled inputs
    dmw: Matrix
    ct: Matrix  # tracked outputs with an integral
    dt_u: Matrix
    dt_w: Matrix
    cl: Matrix  # outputs with limits (design.output_limits): y = yl0 + cl dx + dl_u du + dl_w dw
    dl_u: Matrix
    dl_w: Matrix
    yl0: Matrix


def preview_samples(design: ControlDesign, dt: float) -> int:
    horizons = [t for table in design.preview.values() for t in table]
    return round(max(horizons) / dt) if horizons else 0


def design_point(
    fmu: str | Path,
    design: ControlDesign,
    dt: float,
    noise_std: Mapping[str, float],
    extra_point: Mapping[str, float] | None = None,
) -> PointDesign:
    """Linearise ``fmu`` at the design's operating point (plus ``extra_point``) and design there."""
    inputs, dist = list(design.inputs), list(design.disturbances)
    tracked = list(design.tracking)
    outputs = list(
        dict.fromkeys(
            [
                *design.measured,
                *tracked,
                *(n for n in design.q if n not in (design.states or [])),
                *design.output_limits,
            ]
        )
    )
    point = {**design.operating_point, **(extra_point or {})}
    continuous = linearize(
        fmu, inputs=[*inputs, *dist], outputs=outputs, states=design.states, operating_point=point
    )
    for name in design.q:
        if name not in continuous.states and name not in continuous.outputs:
            raise ConfigError(
                f"design.q: {name!r} is neither a state {list(continuous.states)} nor an output"
            )
    return design_from_model(continuous.discretize(dt), design, noise_std)


def design_from_model(
    model: LinearModel, design: ControlDesign, noise_std: Mapping[str, float]
) -> PointDesign:
    """The LQR design on a sampled linear model (the FMU's or any other, e.g. an analytic one)."""
    assert model.dt is not None
    dt = model.dt
    inputs, dist, tracked = list(design.inputs), list(design.disturbances), list(design.tracking)
    integral = list(design.integral)
    n, m = len(model.states), len(inputs)
    ui, wi = [model.inputs.index(i) for i in inputs], [model.inputs.index(i) for i in dist]
    mi, ti = [model.outputs.index(o) for o in design.measured], [model.outputs.index(o) for o in tracked]
    a, bu, bw = model.a, model.b[:, ui], model.b[:, wi]
    cm, dmu, dmw = model.c[mi], model.d[mi][:, ui], model.d[mi][:, wi]
    ct_all, dtu_all, dtw_all = model.c[ti], model.d[ti][:, ui], model.d[ti][:, wi]
    li = [model.outputs.index(o) for o in design.output_limits]
    # weights: states directly, other outputs through their rows of C
    q = np.zeros((n, n))
    for name, weight in design.q.items():
        if name in model.states:
            i = model.states.index(name)
            q[i, i] += weight
        else:
            row = model.c[model.outputs.index(name)]
            q += weight * np.outer(row, row)
    r = np.diag([design.r.get(name, 1.0) for name in inputs])
    # integrals of the tracking errors: z+ = z + dt (r - y)
    idx = [tracked.index(o) for o in integral]
    ct, dtu, dtw = ct_all[idx], dtu_all[idx], dtw_all[idx]
    ni = len(integral)
    aa = np.block([[a, np.zeros((n, ni))], [-dt * ct, np.eye(ni)]])
    ba = np.vstack([bu, -dt * dtu])
    qa = np.zeros((n + ni, n + ni))
    qa[:n, :n] = q
    qa[n:, n:] = np.diag([design.integral[o] for o in integral])
    p = dare(aa, ba, qa, r)
    gain_inv = np.linalg.inv(r + ba.T @ p @ ba)
    k = gain_inv @ ba.T @ p @ aa
    closed = aa - ba @ k
    steps = preview_samples(design, dt)
    preview = np.zeros((steps + 1, m, n))
    power = np.eye(n + ni)
    for j in range(steps + 1):
        preview[j] = (gain_inv @ ba.T @ power @ p)[:, :n]
        power = power @ closed.T
    # steady-state targets: [A - I, B; C_t, D_t] [x; u] = [-E dw - f0; r - y0_t - D_tw dw]
    lhs = np.block([[a - np.eye(n), bu], [ct_all, dtu_all]])
    nw, nt = len(dist), len(tracked)
    rhs = np.zeros((n + nt, nw + nt + 1))
    rhs[:n, :nw], rhs[:n, -1] = -bw, -model.f0
    rhs[n:, :nw], rhs[n:, nw : nw + nt] = -dtw_all, np.eye(nt)
    target = np.linalg.pinv(lhs) @ rhs
    # steady-state Kalman filter on the measured outputs
    std = np.array([noise_std.get(name, 1e-3) for name in design.measured])
    w = np.diag((design.process_noise * model.nominal) ** 2)
    v = np.diag(std**2)
    pf = dare(a.T, cm.T, w, v)
    kalman = pf @ cm.T @ np.linalg.inv(cm @ pf @ cm.T + v)
    return PointDesign(
        model=model, a=aa, b=ba, q=qa, r=r, k=k, p=p, preview=preview, target=target, kalman=kalman,
        bw=bw, cm=cm, dm=dmu, dmw=dmw, ct=ct, dt_u=dtu, dt_w=dtw,
        cl=model.c[li], dl_u=model.d[li][:, ui], dl_w=model.d[li][:, wi], yl0=model.y0[li],
    )  # fmt: skip


def blend(designs: Sequence[PointDesign], points: Sequence[float], value: float) -> tuple[int, int, float]:
    """The two designs around ``value`` and the weight of the second (held at the ends)."""
    if len(designs) == 1 or value <= points[0]:
        return 0, 0, 0.0
    if value >= points[-1]:
        return len(points) - 1, len(points) - 1, 0.0
    hi = int(np.searchsorted(points, value))
    lo = hi - 1
    return lo, hi, (value - points[lo]) / (points[hi] - points[lo])
