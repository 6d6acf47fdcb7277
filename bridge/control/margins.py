"""Stability margins of a linear design as it runs: the LQR (or unconstrained MPC) with its Kalman filter.

An LQR with full state feedback has generous margins; with an estimator in the loop it has none
guaranteed (LQG), and a filter that trusts the sensors more can leave too little. So the margins
are those of the loop that actually runs, broken at the plant input:

- the plant, sampled: ``x+ = A x + B v``, outputs at the end of a step ``y = C x + D v_prev``;
- the controller as :meth:`LinearController.control` computes it (deviation coordinates, no
  reference or disturbance changes): the filter ``x_hat = x_pred + L (y_m - C_m x_pred - D_m u_prev)``,
  the law ``u = -K [x_hat; z]``, the prediction ``x_pred+ = A x_hat + B u`` and the tracking
  integrals ``z+ = z - dt y_t``.

``u = T(z) v`` is the open loop; the loop closes with ``v = g u``. The **gain interval** is the
range of ``g`` around 1 over which the closed loop stays stable (spectral radius below 1, found
by bisection on the eigenvalues); the **phase margin** and the **stability margin** (the least
distance of the loop's Nyquist curve from -1) come from the frequency response of ``L = -T``,
computed by python-control (``control.stability_margins``). One input is handled exactly; with
several inputs the gain interval is for a common gain on all of them and the phase margin is not
given.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from bridge.control.deps import require
from bridge.control.design import PointDesign
from bridge.control.linear import Matrix

GAIN_SEARCH = (1e-3, 1e3)  # the gain interval is searched within these factors


@dataclass(frozen=True)
class Margins:
    """Margins of one design point. ``gain_low``/``gain_high``: the factors on the controller's
    output between which the loop stays stable (``gain_low`` 0 where the plant is stable alone,
    ``inf`` above where no gain up to 1e3 destabilises it); ``phase_deg``: the phase margin
    in degrees, the least phase change (lag or lead) at a gain crossover that makes the loop pass
    through -1 (``inf`` without a gain crossover); ``stability``: the Nyquist curve's least distance from -1;
    ``radius``: the closed loop's spectral radius (below 1: stable)."""

    radius: float
    gain_low: float
    gain_high: float
    phase_deg: float
    stability: float

    @property
    def stable(self) -> bool:
        return self.radius < 1.0

    def row(self) -> dict[str, float]:
        def db(g: float) -> float:
            return 20 * math.log10(g) if 0 < g < math.inf else (-math.inf if g == 0 else math.inf)

        return {
            "closed_loop_radius": self.radius,
            "gain_margin_low_db": db(self.gain_low),
            "gain_margin_high_db": db(self.gain_high),
            "phase_margin_deg": self.phase_deg,
            "stability_margin": self.stability,
        }


def open_loop(d: PointDesign) -> tuple[Matrix, Matrix, Matrix]:
    """``(Ao, Bo, Cu)``: ``X+ = Ao X + Bo v``, ``u = Cu X`` with ``X = [x_p, v_prev, x_pred, z, u_prev]``."""
    model = d.model
    n, m = model.a.shape[0], d.b.shape[1]
    ni = d.a.shape[0] - n
    a = model.a
    bu = d.b[:n]  # the controlled inputs' columns of B (the augmented B's state rows)
    cm, dm, ct, dtu, gain = d.cm, d.dm, d.ct, d.dt_u, d.kalman
    kx, kz = d.k[:, :n], d.k[:, n:]
    size = n + m + n + ni + m
    ip, iv, ic, iz, iu = 0, n, n + m, 2 * n + m, 2 * n + m + ni
    # x_hat = H X: x_pred + L (C_m x_p + D_m v_prev - C_m x_pred - D_m u_prev)
    h = np.zeros((n, size))
    h[:, ip:iv] = gain @ cm
    h[:, iv:ic] = gain @ dm
    h[:, ic:iz] = np.eye(n) - gain @ cm
    h[:, iu:] = -gain @ dm
    cu = -kx @ h
    cu[:, iz:iu] -= kz
    ao = np.zeros((size, size))
    bo = np.zeros((size, m))
    ao[ip:iv, ip:iv] = a
    bo[ip:iv] = bu
    bo[iv:ic] = np.eye(m)
    ao[ic:iz] = a @ h + bu @ cu
    ao[iz:iu, iz:iu] = np.eye(ni)
    dt = float(model.dt or 0.0)
    ao[iz:iu, ip:iv] = -dt * ct
    ao[iz:iu, iv:ic] = -dt * dtu
    ao[iu:] = cu
    return ao, bo, cu


def _radius(ao: Matrix, bo: Matrix, cu: Matrix, g: float) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(ao + g * bo @ cu))))


def _edge(ao: Matrix, bo: Matrix, cu: Matrix, inside: float, outside: float) -> float:
    """The gain between ``inside`` (stable) and ``outside`` (unstable) where stability ends."""
    for _ in range(60):
        middle = math.sqrt(inside * outside) if inside > 0 else outside / 2
        if _radius(ao, bo, cu, middle) < 1.0:
            inside = middle
        else:
            outside = middle
    return inside


def _gain_interval(ao: Matrix, bo: Matrix, cu: Matrix) -> tuple[float, float]:
    low_end, high_end = GAIN_SEARCH
    grid = np.geomspace(1.0, high_end, 61)
    high = math.inf
    for previous, g in itertools.pairwise(grid):
        if _radius(ao, bo, cu, g) >= 1.0:
            high = _edge(ao, bo, cu, previous, g)
            break
    grid = np.geomspace(1.0, low_end, 61)
    low = 0.0
    for previous, g in itertools.pairwise(grid):
        if _radius(ao, bo, cu, g) >= 1.0:
            low = _edge(ao, bo, cu, previous, g)
            break
    return low, high


def margins(d: PointDesign) -> Margins:
    """The margins of the loop that runs at design point ``d`` (see the module doc)."""
    ao, bo, cu = open_loop(d)
    radius = _radius(ao, bo, cu, 1.0)
    if radius >= 1.0:
        return Margins(radius, math.nan, math.nan, math.nan, math.nan)
    low, high = _gain_interval(ao, bo, cu)
    phase, stability = math.nan, math.nan
    if bo.shape[1] == 1:
        control = require("control", "stability margins of lqr and mpc designs")
        loop = control.ss(ao, bo, -cu, np.zeros((1, 1)), d.model.dt)
        _, phase, stability, *_ = control.stability_margins(loop)
        # the least phase change, lag or lead, that puts the curve through -1 (python-control signs
        # it by its wrapping, which for an unstable plant alone can read negative)
        phase = abs((float(phase) + 180.0) % 360.0 - 180.0) if np.isfinite(phase) else math.inf
    return Margins(radius, low, high, phase, float(stability))
