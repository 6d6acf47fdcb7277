"""Linear MPC on the LQR's error system, with input and rate limits, solved by OSQP.

Over ``horizon`` samples it minimises sum s_j'Q s_j + nu_j'R nu_j + s_N'P s_N (P the LQR's Riccati
solution, so without active limits the first move is the LQR's, preview included) subject to
the inputs' limits and |u_j - u_j-1| <= rate * dt, the previewed target changes entering the
prediction. The QP is condensed (the moves are the unknowns); one OSQP problem per schedule
point, the nearest one chosen at run time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bridge.control.controller import LinearController, _Blended
from bridge.control.deps import require
from bridge.control.design import PointDesign
from bridge.control.linear import Matrix


class _Qp:
    def __init__(self, d: PointDesign, horizon: int, rate: Matrix, dt: float) -> None:
        sparse = require("scipy.sparse", "the mpc baseline")
        osqp = require("osqp", "the mpc baseline")
        a, b, q, r, p = d.a, d.b, d.q, d.r, d.p
        ns, m, n = a.shape[0], b.shape[1], d.model.a.shape[0]
        powers = [np.eye(ns)]
        for _ in range(horizon):
            powers.append(a @ powers[-1])
        su = np.zeros((horizon * ns, horizon * m))
        sd = np.zeros((horizon * ns, horizon * n))
        for j in range(1, horizon + 1):  # s_j = A^j s0 + sum_i<j A^(j-1-i) (B nu_i + [d_i; 0])
            for i in range(j):
                su[(j - 1) * ns : j * ns, i * m : (i + 1) * m] = powers[j - 1 - i] @ b
                sd[(j - 1) * ns : j * ns, i * n : (i + 1) * n] = powers[j - 1 - i][:, :n]
        self.sx = np.vstack(powers[1:])
        qbar = sparse.block_diag([q] * (horizon - 1) + [p]).toarray()
        hessian = su.T @ qbar @ su + np.kron(np.eye(horizon), r)
        self.gradient = su.T @ qbar
        self.sd, self.horizon, self.m = sd, horizon, m
        diff = np.eye(horizon * m) - np.eye(horizon * m, k=-m)
        constraints = sparse.csc_matrix(np.vstack([np.eye(horizon * m), diff]))
        self.rate = np.tile(rate * dt, horizon)
        self.solver: Any = osqp.OSQP()
        n_con = 2 * horizon * m
        self.solver.setup(
            sparse.triu(sparse.csc_matrix(hessian), format="csc"), np.zeros(horizon * m), constraints,
            -np.full(n_con, np.inf), np.full(n_con, np.inf),
            verbose=False, eps_abs=1e-7, eps_rel=1e-7, warm_starting=True, max_iter=20000,
        )  # fmt: skip
        self.failures = 0

    def solve(
        self,
        state: Matrix,
        changes: Matrix,
        *,
        u_star: Matrix,
        u0: Matrix,
        low: Matrix,
        high: Matrix,
        u_prev: Matrix,
    ) -> Matrix | None:
        h, m = self.horizon, self.m
        q = self.gradient @ (self.sx @ state + self.sd @ changes.reshape(-1))
        base = (u0 + u_star[:h]).reshape(-1)  # u_j = base_j + nu_j
        box_lo, box_hi = np.tile(low, h) - base, np.tile(high, h) - base
        step = base - np.concatenate([u_prev, base[:-m]])  # u_j - u_j-1 = nu_j - nu_j-1 + step_j
        rate_lo, rate_hi = -self.rate - step, self.rate - step
        self.solver.update(q=q, l=np.concatenate([box_lo, rate_lo]), u=np.concatenate([box_hi, rate_hi]))
        result = self.solver.solve(raise_error=False)
        x = result.x
        if x is None or not np.all(np.isfinite(x)) or "solved" not in str(result.info.status).lower():
            self.failures += 1
            return None
        return np.asarray(x[:m], dtype=np.float64)


class Mpc(LinearController):
    kind = "mpc"

    def build(self, limits: Any = None) -> None:
        super().build(limits)
        self._qps = [_Qp(d, self.spec.horizon, self._rate, self.dt) for d in self.designs]
        self._nearest = 0

    def horizon_samples(self) -> int:
        return self.spec.horizon

    def _at(self, signals: Any) -> _Blended:
        value = signals[self.spec.schedule.signal] if self.spec.schedule else 0.0
        self._nearest = int(np.argmin(np.abs(np.asarray(self.points) - value)))
        saved, self.designs = self.designs, [self.designs[self._nearest]]
        points, self.points = self.points, [self.points[self._nearest]]
        try:
            return super()._at(signals)
        finally:
            self.designs, self.points = saved, points

    def _law(self, m: _Blended, state: Matrix, x_star: Matrix, u_star: Matrix, u_prev: Matrix) -> Matrix:
        h = self.spec.horizon
        changes = x_star[:h] - x_star[1 : h + 1]
        low = np.array([lo for lo, _ in self._limits])
        high = np.array([hi for _, hi in self._limits])
        move = self._qps[self._nearest].solve(
            state, changes, u_star=u_star, u0=m.u0, low=low, high=high, u_prev=u_prev
        )
        if move is None:  # the LQR law (clipped by the caller) when the solver gives no answer
            return super()._law(m, state, x_star, u_star, u_prev)
        return move

    @property
    def failures(self) -> int:
        return sum(qp.failures for qp in self._qps)
