"""The vehicle model (FMI 2.0 and 3.0 co-simulation) against independent references.

The FMUs are driven with FMPy's slaves directly. References: the same single-track equations
written here again and integrated by scipy's solve_ivp (DOP853, rtol = atol = 1e-11) with the
inputs held over each communication step; the circle geometry of a car driving straight past a
curved path; the linear bicycle model's steady-state yaw-rate gain; the friction limit mu g of
the lateral acceleration; the steering actuator's rate and angle limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from scipy.integrate import solve_ivp

from bridge import models

H = 0.05
P = dict(m=1500.0, Iz=2250.0, lf=1.2, lr=1.4, Cf=80000.0, Cr=100000.0, mu=0.9, shape=1.4, g=9.81,
         delta_max=0.5, steer_rate_max=0.6, steer_tau=0.05, v_min=1.0)  # fmt: skip
STATES = ("lateral_error", "heading_error", "lateral_velocity", "yaw_rate", "steer_angle", "distance")
Run = Callable[..., dict[str, np.ndarray]]


def rhs(p: dict[str, float], u: Sequence[float]) -> Callable[[float, np.ndarray], list[float]]:
    """The model's equations, written from the model description (README), not from model.c."""
    cmd, speed, kappa = u
    vx = max(speed, p["v_min"])

    def tyre(alpha: float, stiffness: float, fz: float) -> float:
        peak = p["mu"] * fz
        return peak * math.sin(p["shape"] * math.atan(stiffness / (p["shape"] * peak) * alpha))

    def f(t: float, x: np.ndarray) -> list[float]:
        e_y, e_psi, vy, r, delta, _ = x
        wheelbase = p["lf"] + p["lr"]
        fyf = tyre(delta - math.atan((vy + p["lf"] * r) / vx), p["Cf"], p["m"] * p["g"] * p["lr"] / wheelbase)
        fyr = tyre(-math.atan((vy - p["lr"] * r) / vx), p["Cr"], p["m"] * p["g"] * p["lf"] / wheelbase)
        s_dot = (vx * math.cos(e_psi) - vy * math.sin(e_psi)) / (1 - kappa * e_y)
        target = min(max(cmd, -p["delta_max"]), p["delta_max"])
        return [
            vy * math.cos(e_psi) + vx * math.sin(e_psi),
            r - kappa * s_dot,
            (fyf * math.cos(delta) + fyr) / p["m"] - vx * r,
            (p["lf"] * fyf * math.cos(delta) - p["lr"] * fyr) / p["Iz"],
            p["steer_rate_max"] * math.tanh((target - delta) / (p["steer_tau"] * p["steer_rate_max"])),
            s_dot,
        ]

    return f


def reference(p: dict[str, float], inputs: np.ndarray, x0: Sequence[float]) -> np.ndarray:
    x, rows = np.asarray(x0, dtype=float), [np.asarray(x0, dtype=float)]
    for u in inputs:
        x = solve_ivp(rhs(p, u), (0.0, H), x, method="DOP853", rtol=1e-11, atol=1e-11).y[:, -1]
        rows.append(x)
    return np.array(rows)


@pytest.fixture
def run(tmp_path: Path) -> Iterator[Run]:
    """Factory: simulate a vehicle FMU with inputs held per step (rows: steer_cmd, v_x, path_curvature)."""
    opened: list[Any] = []

    def simulate(version: str, inputs: np.ndarray, **parameters: float) -> dict[str, np.ndarray]:
        path = models.example_fmu("vehicle", version, "cs")
        description = read_model_description(str(path))
        vr = {v.name: v.valueReference for v in description.modelVariables}
        slave_class = FMU3Slave if version == "3.0" else FMU2Slave
        directory = extract(str(path), unzipdir=str(tmp_path / f"u{len(opened)}"))
        fmu = slave_class(
            guid=description.guid, unzipDirectory=directory,
            modelIdentifier=description.coSimulation.modelIdentifier, instanceName="vehicle",
        )  # fmt: skip
        fmu.instantiate()
        opened.append(fmu)
        setter = fmu.setFloat64 if version == "3.0" else fmu.setReal
        getter = fmu.getFloat64 if version == "3.0" else fmu.getReal
        if version == "3.0":
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        if parameters:
            setter([vr[k] for k in parameters], list(parameters.values()))
        setter([vr["steer_cmd"], vr["v_x"], vr["path_curvature"]], list(inputs[0]))
        fmu.exitInitializationMode()
        names = [*STATES, "lateral_accel", "speed", "curvature"]
        rows = [getter([vr[n] for n in names])]
        for k, u in enumerate(inputs):
            setter([vr["steer_cmd"], vr["v_x"], vr["path_curvature"]], list(u))
            fmu.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
            rows.append(getter([vr[n] for n in names]))
        table = np.array(rows)
        return {name: table[:, i] for i, name in enumerate(names)}

    yield simulate
    for fmu in opened:  # freed without terminate: one test leaves an instance in the error state
        fmu.freeInstance()


def drive(n: int) -> np.ndarray:
    """A demanding input sequence: steering into the tyre's saturation, speed 8 -> 24 m/s, bends."""
    t = np.arange(n) * H
    steer = 0.12 * np.sin(0.9 * t) + 0.08 * (t > 3) - 0.3 * ((t > 6) & (t < 7))
    return np.column_stack([steer, 8.0 + 0.8 * t, 0.03 * np.sin(0.4 * t)])


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_trajectory_matches_solve_ivp(run: Run, version: str) -> None:
    inputs = drive(200)
    result = run(version, inputs, e_y0=0.4, e_psi0=-0.05)
    expected = reference(P, inputs, [0.4, -0.05, 0.0, 0.0, 0.0, 0.0])
    got = np.column_stack([result[name] for name in STATES])
    scale = np.maximum(np.abs(expected).max(axis=0), 1e-3)
    error = (np.abs(got - expected) / scale).max()
    assert error < 1e-7, error  # RK4 with 1 ms substeps: measured 2e-10 of full scale
    assert np.abs(expected[:, 4]).max() > 0.2  # the trajectory really left the linear tyre range


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_driving_straight_past_a_circular_path_follows_the_circle_geometry(run: Run, version: str) -> None:
    """Zero steering: the car keeps its line; its errors to a circle of radius R it started tangent to
    are e_y = R - sqrt(R^2 + d^2), e_psi = -atan(d / R), s = R atan(d / R) after d = v t."""
    radius, speed, n = 50.0, 12.0, 100
    inputs = np.tile([0.0, speed, 1.0 / radius], (n, 1))
    result = run(version, inputs)
    d = speed * H * np.arange(n + 1)
    np.testing.assert_allclose(result["lateral_error"], radius - np.hypot(radius, d), atol=1e-8)
    np.testing.assert_allclose(result["heading_error"], -np.arctan(d / radius), atol=1e-9)
    np.testing.assert_allclose(result["distance"], radius * np.arctan(d / radius), atol=1e-8)
    assert np.abs(result["yaw_rate"]).max() == 0.0 and np.abs(result["lateral_accel"]).max() == 0.0


def test_small_steering_gives_the_linear_bicycle_yaw_gain(run: Run) -> None:
    """r / delta = v / (L + K v^2) with the understeer gradient K = m (lr Cr - lf Cf) / (L Cf Cr)."""
    speed, delta = 15.0, 0.005
    result = run("2.0", np.tile([delta, speed, 0.0], (200, 1)))
    wheelbase = P["lf"] + P["lr"]
    understeer = P["m"] * (P["lr"] * P["Cr"] - P["lf"] * P["Cf"]) / (wheelbase * P["Cf"] * P["Cr"])
    expected = speed * delta / (wheelbase + understeer * speed**2)
    assert result["yaw_rate"][-1] == pytest.approx(expected, rel=2e-3)  # tyre curve slightly below linear


def test_lateral_acceleration_saturates_at_the_friction_limit(run: Run) -> None:
    result = run("3.0", np.tile([0.5, 20.0, 0.0], (60, 1)), mu=0.7)
    limit = 0.7 * P["g"]
    assert np.abs(result["lateral_accel"]).max() <= limit * (1 + 1e-12)
    peak = np.abs(result["lateral_accel"]).max()
    assert peak > 0.9 * limit  # both axles near their peak force at once (measured 0.93)
    assert result["lateral_accel"][-1] < 0.9 * peak  # past the peak the tyre force falls (C > 1)


def test_steering_actuator_limits_rate_and_angle(run: Run) -> None:
    result = run("2.0", np.tile([2.0, 10.0, 0.0], (60, 1)))  # command beyond delta_max
    rate = np.diff(result["steer_angle"]) / H
    assert rate.max() <= P["steer_rate_max"] + 1e-12 and rate.max() > 0.95 * P["steer_rate_max"]
    assert result["steer_angle"].max() <= P["delta_max"] and result["steer_angle"][-1] > 0.499


def test_speed_below_v_min_uses_v_min_and_bad_parameters_are_rejected(run: Run) -> None:
    result = run("2.0", np.tile([0.0, 0.0, 0.0], (3, 1)))
    assert result["speed"][-1] == P["v_min"]
    with pytest.raises(Exception, match=r"ExitInitializationMode"):
        run("2.0", np.tile([0.0, 10.0, 0.0], (3, 1)), mu=-1.0)
