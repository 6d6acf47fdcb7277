"""Linearisation of FMUs through model exchange against the plants' closed forms, and the
Riccati solvers against scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, solve_discrete_are

from bridge.control.linear import linearize
from bridge.control.riccati import dare, finite_horizon_gains, lqr_gain
from bridge.errors import ConfigError
from bridge.models import example_fmu


def cartpole_closed_form(
    m_cart: float, m_pole: float, length: float, g: float
) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's cart-pole equations linearised upright (x, x_dot, theta, theta_dot; force)."""
    total = m_cart + m_pole
    denominator = length * (4.0 / 3.0 - m_pole / total)
    theta_theta = g / denominator
    theta_force = -1.0 / (total * denominator)
    x_theta = -m_pole * length * theta_theta / total
    x_force = 1.0 / total - m_pole * length * theta_force / total
    a = np.array([[0, 1, 0, 0], [0, 0, x_theta, 0], [0, 0, 0, 1], [0, 0, theta_theta, 0]], dtype=float)
    b = np.array([[0.0], [x_force], [0.0], [theta_force]])
    return a, b


def test_cartpole_linearisation_matches_the_closed_form() -> None:
    point = {"m_cart": 1.3, "m_pole": 0.2, "length": 0.6}
    lin = linearize(
        example_fmu("cartpole", "2.0", "me"), inputs=["force"], outputs=["theta"], operating_point=point
    )
    a, b = cartpole_closed_form(1.3, 0.2, 0.6, 9.8)
    assert lin.states == ("x", "x_dot", "theta", "theta_dot")
    np.testing.assert_allclose(lin.a, a, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(lin.b, b, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(lin.c, [[0, 0, 1, 0]], atol=1e-9)
    np.testing.assert_allclose(lin.f0, 0.0, atol=1e-12)  # upright is an equilibrium


def test_fmi3_cartpole_gives_the_same_model() -> None:
    two = linearize(example_fmu("cartpole", "2.0", "me"), inputs=["force"])
    three = linearize(example_fmu("cartpole", "3.0", "me"), inputs=["force"])
    np.testing.assert_allclose(three.a, two.a, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(three.b, two.b, rtol=1e-9, atol=1e-12)


def test_dc_motor_linearisation_and_sampling_match_the_closed_form() -> None:
    r, ind, k, j, b = 1.2, 0.003, 0.09, 0.012, 0.0002
    point = {"R": r, "L": ind, "K": k, "J": j, "b": b, "omega": 50.0, "voltage": 6.0}
    lin = linearize(
        example_fmu("dcmotor", "2.0", "me"), inputs=["voltage", "load_torque"], outputs=["omega", "torque"],
        operating_point=point,
    )  # fmt: skip
    a = np.array([[-r / ind, -k / ind], [k / j, -b / j]])
    bu = np.array([[1 / ind, 0.0], [0.0, -1 / j]])
    assert lin.states == ("current", "omega")
    np.testing.assert_allclose(lin.a, a, rtol=1e-6)
    np.testing.assert_allclose(lin.b, bu, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(lin.c, np.array([[0, 1], [k, 0]], dtype=float), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(lin.f0, [(6.0 - k * 50.0) / ind, -b * 50.0 / j], rtol=1e-9)
    sampled = lin.discretize(0.01)
    np.testing.assert_allclose(sampled.a, expm(a * 0.01), rtol=1e-8, atol=1e-12)
    # zero-order hold input matrix: integral of e^(A s) ds B = A^-1 (e^(A dt) - I) B
    np.testing.assert_allclose(
        sampled.b, np.linalg.solve(a, expm(a * 0.01) - np.eye(2)) @ bu, rtol=1e-7, atol=1e-12
    )


def test_vehicle_linearisation_is_the_linear_single_track_model() -> None:
    lin = linearize(
        example_fmu("vehicle", "2.0", "me"), inputs=["steer_cmd", "path_curvature"],
        states=["lateral_error", "heading_error", "lateral_velocity", "yaw_rate", "steer_angle"],
        operating_point={"v_x": 15.0},
    )  # fmt: skip
    m, iz, lf, lr, cf, cr, v, tau = 1500.0, 2250.0, 1.2, 1.4, 80000.0, 100000.0, 15.0, None
    tau = 1.0 / -lin.a[4, 4]
    expected = np.array(
        [
            [0, v, 1, 0, 0],
            [0, 0, 0, 1, 0],
            [0, 0, -(cf + cr) / (m * v), (lr * cr - lf * cf) / (m * v) - v, cf / m],
            [0, 0, (lr * cr - lf * cf) / (iz * v), -(lf**2 * cf + lr**2 * cr) / (iz * v), lf * cf / iz],
            [0, 0, 0, 0, -1 / tau],
        ]
    )
    np.testing.assert_allclose(lin.a, expected, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(
        lin.b, np.array([[0, 0], [0, -v], [0, 0], [0, 0], [1 / tau, 0]], dtype=float), rtol=1e-6, atol=1e-8
    )


def test_unknown_state_and_co_simulation_only_fmu_are_clear_errors() -> None:
    with pytest.raises(ConfigError, match="not continuous states"):
        linearize(example_fmu("cartpole", "2.0", "me"), inputs=["force"], states=["angle"])
    with pytest.raises(ConfigError, match="needs model exchange"):
        linearize(example_fmu("cartpole", "2.0", "cs"), inputs=["force"])


def test_dare_and_lqr_gain_match_scipy() -> None:
    rng = np.random.default_rng(3)
    for n, m in [(2, 1), (4, 1), (5, 2), (6, 3)]:
        a = rng.normal(size=(n, n)) * 0.8
        b = rng.normal(size=(n, m))
        q = np.diag(rng.uniform(0.1, 2.0, n))
        r = np.diag(rng.uniform(0.1, 2.0, m))
        p = dare(a, b, q, r)
        np.testing.assert_allclose(p, solve_discrete_are(a, b, q, r), rtol=1e-8, atol=1e-10)
        k, _ = lqr_gain(a, b, q, r)
        assert np.max(np.abs(np.linalg.eigvals(a - b @ k))) < 1.0


def test_finite_horizon_gains_converge_to_the_infinite_horizon_gain() -> None:
    lin = linearize(example_fmu("cartpole", "2.0", "me"), inputs=["force"]).discretize(0.02)
    q, r = np.diag([1.0, 0.1, 10.0, 0.1]), np.array([[0.1]])
    k, p = lqr_gain(lin.a, lin.b, q, r)
    gains = finite_horizon_gains(lin.a, lin.b, q, r, terminal=np.zeros((4, 4)), n=2000)
    np.testing.assert_allclose(gains[0], k, rtol=1e-6)
    # with the Riccati solution as terminal weight every finite-horizon gain is the stationary one
    for gain in finite_horizon_gains(lin.a, lin.b, q, r, terminal=p, n=5):
        np.testing.assert_allclose(gain, k, rtol=1e-8)


def test_unstabilisable_design_is_a_clear_error() -> None:
    a = np.diag([1.5, 0.5])
    b = np.array([[0.0], [1.0]])  # the unstable mode is not reachable
    with pytest.raises(ConfigError, match="no stabilising solution"):
        dare(a, b, np.eye(2), np.eye(1))
