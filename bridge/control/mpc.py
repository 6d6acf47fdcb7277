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
    """The condensed QP of one design point: the moves ``nu`` (and, with output limits, one slack per
    limited output and sample, penalised linearly and quadratically so that the limits hold
    whenever they can and the problem stays feasible when they cannot)."""

    def __init__(
        self, d: PointDesign, horizon: int, rate: Matrix, dt: float, output_limits: list[tuple[float, float]]
    ) -> None:
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
        self.sd, self.horizon, self.m, self.n, self.ns = sd, horizon, m, n, ns
        self.design = d
        diff = np.eye(horizon * m) - np.eye(horizon * m, k=-m)
        blocks = [np.eye(horizon * m), diff]
        self.rate = np.tile(rate * dt, horizon)
        k = d.cl.shape[0]
        self.k, self.slack_cost = k, np.zeros(0)
        if k:  # y_j = free_j + G nu (j = 1..h): the limited outputs after each move
            g = np.zeros((horizon * k, horizon * m))
            for j in range(1, horizon + 1):
                rows = slice((j - 1) * k, j * k)
                g[rows] = d.cl @ su[(j - 1) * ns : (j - 1) * ns + n]
                g[rows, (j - 1) * m : j * m] += d.dl_u
            weight = 1e3 * max(1.0, float(np.max(np.diag(hessian))))
            eye, zero = np.eye(horizon * k), np.zeros((horizon * k, horizon * m))
            hessian = sparse.block_diag([hessian, weight * eye]).toarray()
            blocks = [np.hstack([blk, np.zeros((blk.shape[0], horizon * k))]) for blk in blocks]
            blocks += [np.hstack([g, -eye]), np.hstack([g, eye]), np.hstack([zero, eye])]
            self.slack_cost = np.full(horizon * k, weight)
            self.y_low = np.tile([lo for lo, _ in output_limits], horizon)
            self.y_high = np.tile([hi for _, hi in output_limits], horizon)
        self.solver: Any = osqp.OSQP()
        constraints = sparse.csc_matrix(np.vstack(blocks))
        n_con = constraints.shape[0]
        self.solver.setup(
            sparse.triu(sparse.csc_matrix(hessian), format="csc"), np.zeros(hessian.shape[0]), constraints,
            -np.full(n_con, np.inf), np.full(n_con, np.inf),
            verbose=False, eps_abs=1e-7, eps_rel=1e-7, warm_starting=True, max_iter=20000,
        )  # fmt: skip
        self.failures = 0

    def _free_outputs(self, s: Matrix, x_star: Matrix, u_star: Matrix, w: Matrix) -> Matrix:
        """The limited outputs at samples 1..h with every move zero (the part the moves do not set)."""
        d, h, n, ns = self.design, self.horizon, self.n, self.ns
        states = s.reshape(h, ns)[:, :n] + x_star[1 : h + 1]
        y = d.yl0 + states @ d.cl.T + u_star[:h] @ d.dl_u.T + w[:h] @ d.dl_w.T
        return np.asarray(y, dtype=np.float64).reshape(-1)

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
        x_star: Matrix,
        w: Matrix,
    ) -> Matrix | None:
        h, m = self.horizon, self.m
        free_s = self.sx @ state + self.sd @ changes.reshape(-1)
        q = self.gradient @ free_s
        base = (u0 + u_star[:h]).reshape(-1)  # u_j = base_j + nu_j
        box_lo, box_hi = np.tile(low, h) - base, np.tile(high, h) - base
        step = base - np.concatenate([u_prev, base[:-m]])  # u_j - u_j-1 = nu_j - nu_j-1 + step_j
        rate_lo, rate_hi = -self.rate - step, self.rate - step
        lower, upper = [box_lo, rate_lo], [box_hi, rate_hi]
        if self.k:
            free_y = self._free_outputs(free_s, x_star, u_star, w)
            inf = np.full(free_y.size, np.inf)
            lower += [-inf, self.y_low - free_y, np.zeros(free_y.size)]
            upper += [self.y_high - free_y, inf, inf]
            q = np.concatenate([q, self.slack_cost])
        self.solver.update(q=q, l=np.concatenate(lower), u=np.concatenate(upper))
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
        limits = list(self.spec.output_limits.values())
        self._qps = [_Qp(d, self.spec.horizon, self._rate, self.dt, limits) for d in self.designs]

    def horizon_samples(self) -> int:
        return self.spec.horizon

    def _law(
        self, m: _Blended, state: Matrix, x_star: Matrix, u_star: Matrix, u_prev: Matrix, *, w: Matrix
    ) -> Matrix:
        """The first move of the plan of each neighbouring schedule point, blended with the weight
        the LQR's gains get (one plan off the schedule or at a point): a plan on the nearest
        point's model alone is off by half a point's spacing between two points."""
        h = self.spec.horizon
        changes = x_star[:h] - x_star[1 : h + 1]
        low = np.array([lo for lo, _ in self._limits])
        high = np.array([hi for _, hi in self._limits])
        lo, hi, t = self._blend
        moves = []
        for index in (lo,) if t == 0.0 or lo == hi else (lo, hi):
            move = self._qps[index].solve(
                state, changes, u_star=u_star, u0=m.u0, low=low, high=high, u_prev=u_prev, x_star=x_star, w=w
            )
            if move is None:  # the LQR law (clipped by the caller) when a solver gives no answer
                return super()._law(m, state, x_star, u_star, u_prev, w=w)
            moves.append(move)
        return moves[0] if len(moves) == 1 else (1.0 - t) * moves[0] + t * moves[1]

    @property
    def failures(self) -> int:
        return sum(qp.failures for qp in self._qps)
