"""Discrete Riccati equations: the infinite-horizon solution and the finite-horizon recursion."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from bridge.errors import ConfigError

Matrix = NDArray[np.float64]


def dare(a: Matrix, b: Matrix, q: Matrix, r: Matrix, *, tol: float = 1e-12, max_iter: int = 200) -> Matrix:
    """The stabilising P of P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q, by the structure-preserving
    doubling algorithm (quadratic convergence; needs (A, B) stabilisable and (A, Q) detectable)."""
    n = a.shape[0]
    ak, gk, hk = a.copy(), b @ np.linalg.solve(r, b.T), q.copy()
    identity = np.eye(n)
    for _ in range(max_iter):
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging iteration ends below
            ak, gk, hk, converged = _double(ak, gk, hk, identity, tol)
        if not np.all(np.isfinite(hk)):
            break
        if converged:
            symmetric: Matrix = 0.5 * (hk + hk.T)
            return symmetric
    raise ConfigError(
        "the Riccati equation has no stabilising solution: check that every unstable mode is "
        "controlled by the inputs and weighted in q (the states, inputs and weights of the design)"
    )


def _double(
    ak: Matrix, gk: Matrix, hk: Matrix, identity: Matrix, tol: float
) -> tuple[Matrix, Matrix, Matrix, bool]:
    """One doubling step (A, G, H) -> (A (I + GH)^-1 A, G + A (I + GH)^-1 G A', H + A'H (I + GH)^-1 A)."""
    w = identity + gk @ hk
    a_w = ak @ np.linalg.inv(w)
    h_next = hk + ak.T @ hk @ np.linalg.solve(w, ak)
    g_next = gk + a_w @ gk @ ak.T
    converged = bool(np.linalg.norm(h_next - hk, 1) <= tol * max(1.0, float(np.linalg.norm(h_next, 1))))
    return a_w @ ak, g_next, h_next, converged


def lqr_gain(a: Matrix, b: Matrix, q: Matrix, r: Matrix) -> tuple[Matrix, Matrix]:
    """K and P of the discrete LQR u = -K x minimising the sum of x'Qx + u'Ru."""
    p = dare(a, b, q, r)
    k = np.asarray(np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a), dtype=np.float64)
    return k, p


def finite_horizon_gains(
    a: Matrix, b: Matrix, q: Matrix, r: Matrix, *, terminal: Matrix, n: int
) -> list[Matrix]:
    """K_0 .. K_{n-1} of the finite-horizon LQR with terminal weight ``terminal`` (backward recursion)."""
    p, gains = terminal, []
    for _ in range(n):
        k = np.asarray(np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a), dtype=np.float64)
        p = q + a.T @ p @ (a - b @ k)
        gains.append(k)
    return gains[::-1]
