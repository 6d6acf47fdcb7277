"""Model exchange with the native fixed-step loop (``solver="rk4"`` / ``"euler"``), checked against
closed forms (bouncing ball, stair), the matrix exponential (DC motor), FMPy's own forward Euler,
the co-simulation variant with the same RK4 substeps (cart-pole) and the CVode path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fmpy import simulate_fmu
from scipy.linalg import expm

from bridge.errors import ConfigError, StepError
from bridge.fmu import Model
from bridge.models import example_fmu
from tests.fmu.test_me_events import PERIOD, H, closed_form, run_stair

G, E, H0, V_MIN = 9.81, 0.7, 1.0, 0.1
BALL_H = 0.01


def ball_closed_form(times: np.ndarray) -> np.ndarray:
    """(h, v, bounces) of the bouncing ball at ``times``: parabolas between analytic contacts."""
    rows, t0, h, v, bounces, rest = [], 0.0, H0, 0.0, 0, False
    for t in times:
        while not rest:
            contact = t0 + (v + math.sqrt(v * v + 2 * G * h)) / G
            if contact > t:
                break
            v, h, t0, bounces = E * (G * (contact - t0) - v), 0.0, contact, bounces + 1
            if v <= V_MIN:
                v, rest = 0.0, True
        dt = t - t0
        rows.append((0.0, 0.0, bounces) if rest else (h + v * dt - G * dt * dt / 2, v - G * dt, bounces))
    return np.array(rows)


def run_ball(model: Model, samples: int) -> np.ndarray:
    outputs = model.signals(["h", "v", "bounces"])
    rows = [outputs.read()]
    for _ in range(samples):
        model.advance(1)
        rows.append(outputs.read())
    return np.array(rows)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_bounces_match_the_closed_form(version: str) -> None:
    with Model(example_fmu("bouncing_ball", version, "me"), step_size_s=BALL_H, solver="rk4") as model:
        model.initialize()
        ours = run_ball(model, 300)
    expected = ball_closed_form(np.arange(301) * BALL_H)
    # RK4 integrates a parabola exactly and the contacts are bisected to 1e-13 s: rounding only.
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-9)
    assert ours[-1, 2] == 11  # every bounce, in the sample of its closed-form contact time


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_event_samples_equal_those_of_cvode(version: str) -> None:
    runs = {}
    for solver in ("rk4", "cvode"):
        with Model(example_fmu("bouncing_ball", version, "me"), step_size_s=BALL_H, solver=solver) as model:
            model.initialize()
            runs[solver] = run_ball(model, 300)
    np.testing.assert_array_equal(runs["rk4"][:, 2], runs["cvode"][:, 2])
    # CVode (rtol 1e-6) errs by up to 4e-7 s in a contact time; over eleven bounces that compounds
    # to 8e-4 m/s (measured), where RK4 stays within 1e-9 of the closed form.
    np.testing.assert_allclose(runs["rk4"], runs["cvode"], rtol=0, atol=2e-3)


@pytest.mark.parametrize("solver", ["rk4", "euler"])
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_time_events_discrete_inputs_and_tunables(version: str, solver: str) -> None:
    with Model(example_fmu("stair", version, "me"), step_size_s=H, solver=solver, solver_substeps=3) as model:
        model.initialize({"period": PERIOD})
        model.set({"step": 1})
        ours = run_stair(model, 20)
    np.testing.assert_allclose(ours, closed_form(20), rtol=0, atol=1e-9)  # x is linear: exact


@pytest.mark.parametrize("policy", ["restore", "reset", "reinstantiate", "auto"])
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_every_episode_repeats_the_first(version: str, policy: str) -> None:
    stair, ball = [], []
    with (
        Model(example_fmu("stair", version, "me"), step_size_s=H, reset_policy=policy, solver="rk4") as s,
        Model(
            example_fmu("bouncing_ball", version, "me"), step_size_s=BALL_H, reset_policy=policy, solver="rk4"
        ) as b,
    ):
        for _ in range(5):
            s.reset({"period": PERIOD})
            stair.append(run_stair(s, 12))
            b.reset({"e": 0.8})
            ball.append(run_ball(b, 60))
    np.testing.assert_allclose(stair[0], closed_form(12), rtol=0, atol=1e-9)
    assert ball[0][-1, 2] >= 1  # a bounce inside the episode
    for episode in (1, 4):
        np.testing.assert_array_equal(stair[episode], stair[0])
        np.testing.assert_array_equal(ball[episode], ball[0])


def dcmotor_exact(volts: list[float], h: float) -> np.ndarray:
    """[omega, current] after each zero-order-held voltage, by the matrix exponential."""
    r, l_, k, j, b = 1.0, 2.5e-3, 0.1, 0.01, 1e-4
    a = np.array([[-r / l_, -k / l_], [k / j, -b / j]])
    m = expm(np.block([[a, np.array([[1 / l_], [0.0]])], [np.zeros((1, 3))]]) * h)
    x, rows = np.zeros(2), []
    for u in volts:
        x = m[:2, :2] @ x + m[:2, 2] * u
        rows.append((x[1], x[0]))
    return np.array(rows)


def test_dcmotor_rk4_matches_the_matrix_exponential() -> None:
    volts = [24.0 * math.sin(0.1 * k) for k in range(200)]
    path = example_fmu("dcmotor", "2.0", "me")
    with Model(path, step_size_s=0.01, solver="rk4", solver_substeps=20) as model:
        model.initialize()
        voltage, outputs = model.signals(["voltage"], writable=True), model.signals(["omega", "current"])
        rows = []
        for u in volts:
            voltage.write([u])
            model.advance(1)
            rows.append(outputs.read())
    exact = dcmotor_exact(volts, 0.01)
    scale = np.abs(exact).max(axis=0)  # full scale: ~200 rad/s, ~20 A
    assert np.abs((np.array(rows) - exact) / scale).max() < 1e-6  # RK4 at 0.5 ms, |lambda h| = 0.2


def test_euler_equals_fmpy_forward_euler() -> None:
    path, substeps, h = example_fmu("dcmotor", "2.0", "me"), 10, 0.01
    with Model(path, step_size_s=h, solver="euler", solver_substeps=substeps) as model:
        model.initialize({"voltage": 12.0, "load_torque": 0.05})
        outputs = model.signals(["omega", "current"])
        rows = [outputs.read()]
        for _ in range(100):
            model.advance(1)
            rows.append(outputs.read())
    ref = simulate_fmu(
        str(path),
        fmi_type="ModelExchange",
        solver="Euler",
        step_size=h / substeps,
        output_interval=h / substeps,
        stop_time=1.0,
        start_values={"voltage": 12.0, "load_torque": 0.05},
        output=["omega", "current"],
    )
    expected = np.column_stack([ref["omega"], ref["current"]])[::substeps][:101]
    np.testing.assert_allclose(np.array(rows), expected, rtol=1e-12, atol=1e-12)
    assert rows[-1][0] > 50  # the motor really spun up


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_cartpole_rk4_equals_co_simulation_with_the_same_substeps(version: str) -> None:
    runs = {}
    for interface, extra in (("cs", {}), ("me", {"solver": "rk4", "solver_substeps": 20})):
        # The CS variant integrates with RK4 substeps of solver_step = 1 ms: 20 per 0.02 s step.
        with Model(example_fmu("cartpole", version, interface), step_size_s=0.02, **extra) as model:  # type: ignore[arg-type]
            model.initialize({"theta0": 0.05})
            force, state = model.signals(["force"], writable=True), model.signals(["x", "theta"])
            rows = []
            for k in range(100):
                force.write([5.0 * math.sin(0.3 * k)])
                model.advance(1)
                rows.append(state.read())
            runs[interface] = np.array(rows)
    np.testing.assert_allclose(runs["me"], runs["cs"], rtol=0, atol=1e-10)
    assert np.abs(runs["me"][:, 1]).max() > 0.5  # the pole really fell


@pytest.mark.parametrize("solver", ["rk4", "cvode"])
def test_a_state_event_that_terminates_ends_in_the_same_sample(solver: str) -> None:
    with Model(example_fmu("cartpole", "2.0", "me"), step_size_s=0.02, solver=solver) as model:  # type: ignore[arg-type]
        model.initialize({"track_limit": 0.3, "x_dot0": 1.0})
        samples = 0
        while not model.advance(1):
            samples += 1
        x = model.get(["x"])["x"]
    assert samples == 14  # |x| reaches 0.3 m in sample 15 (t = 0.28 .. 0.30 s, pole tilting)
    assert x == pytest.approx(0.3, abs=1e-6)  # stopped at the crossing, not at the sample's end


@pytest.mark.parametrize(
    ("fmu", "kwargs", "match"),
    [
        (("cartpole", "2.0", "cs"), {"solver": "rk4"}, "integrates FMI 2.0/3.0 model exchange"),
        (("cartpole", "1.0", "me"), {"solver": "euler"}, "choose interface 'me' \\(FMI 2.0/3.0\\)"),
        (("cartpole", "2.0", "me"), {"solver": "dopri"}, "solver 'dopri' is unknown"),
        (("cartpole", "2.0", "me"), {"solver": "rk4", "solver_substeps": 0}, "whole number >= 1"),
    ],
)
def test_bad_solver_settings_are_refused(
    fmu: tuple[str, str, str], kwargs: dict[str, object], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        Model(example_fmu(*fmu), step_size_s=0.02, interface=fmu[2], **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_an_fmi_call_the_fmu_rejects_is_a_step_error_with_its_log(version: str) -> None:
    with Model(example_fmu("cartpole", version, "me"), step_size_s=0.02, solver="rk4") as model:
        model.initialize()
        model.backend.fmu.terminate()  # behind the model's back: the FMU now refuses every step call
        with pytest.raises(StepError, match=f"fmi{version[0]}SetTime returned Error at t=0 s") as caught:
            model.advance(1)
        assert any("not allowed in terminated" in line for line in caught.value.log)
        model.reset()
        model.advance(1)  # usable again after a reset
        assert model.time_s == pytest.approx(0.02)
