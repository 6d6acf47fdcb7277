"""The lqr and mpc baselines in closed loop with the real FMUs, and against independent computations."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from agents.evaluate import baseline_settings, run_episode
from agents.policies import ModelBased, make_policy
from agents.residual import ResidualWrapper
from bridge.control.design import design_from_model
from bridge.control.linear import LinearModel, linearize
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment import load_experiment
from bridge.experiment.control import ControlDesign
from bridge.experiment.examples import example_experiment
from bridge.models import example_fmu

VEHICLE_DESIGN: dict[str, Any] = {
    "inputs": ["steer_cmd"],
    "states": ["lateral_error", "heading_error", "lateral_velocity", "yaw_rate", "steer_angle"],
    "measured": ["lateral_error", "heading_error", "yaw_rate", "steer_angle"],
    "tracking": {"lateral_error": "lateral_ref"},
    "q": {"lateral_error": 1.0, "heading_error": 1.0},
    "r": {"steer_cmd": 1.0},
    "disturbances": {"path_curvature": "curvature"},
    "preview": {"path_curvature": {0.5: "kappa_ahead_05", 1.0: "kappa_ahead_10"}},
    "operating_point": {"v_x": 15.0},
}


@pytest.fixture(scope="module")
def vehicle() -> Any:
    env = FmuEnv(example_experiment("vehicle_path"))
    yield env
    env.close()


def test_closed_loop_poles_from_the_fmu_match_the_analytic_cartpole() -> None:
    m_cart, m_pole, length, g = 1.0, 0.1, 0.5, 9.8
    total = m_cart + m_pole
    den = length * (4.0 / 3.0 - m_pole / total)
    a = np.array(
        [[0, 1, 0, 0], [0, 0, -m_pole * length * g / den / total, 0], [0, 0, 0, 1], [0, 0, g / den, 0]]
    )
    b = np.array([[0.0], [1 / total + m_pole * length / (total**2 * den)], [0.0], [-1 / (total * den)]])
    names = ("x", "x_dot", "theta", "theta_dot")
    analytic = LinearModel(
        a=a, b=b, c=np.eye(4), d=np.zeros((4, 1)), states=names, inputs=("force",), outputs=names,
        x0=np.zeros(4), u0=np.zeros(1), y0=np.zeros(4), f0=np.zeros(4), nominal=np.ones(4),
    )  # fmt: skip
    design = ControlDesign(
        inputs=["force"], measured=list(names), q={"x": 1.0, "theta": 10.0}, r={"force": 0.1}
    )
    fmu = linearize(example_fmu("cartpole", "2.0", "me"), inputs=["force"], outputs=list(names))
    mine = design_from_model(fmu.discretize(0.02), design, {})
    reference = design_from_model(analytic.discretize(0.02), design, {})
    poles = np.sort_complex(np.linalg.eigvals(mine.a - mine.b @ mine.k))
    expected = np.sort_complex(np.linalg.eigvals(reference.a - reference.b @ reference.k))
    np.testing.assert_allclose(poles, expected, rtol=1e-6, atol=1e-9)
    assert np.all(np.abs(poles) < 1.0)


def test_lqr_balances_the_cartpole_for_whole_episodes() -> None:
    experiment = example_experiment("cartpole_continuous")
    env = FmuEnv(experiment)
    policy = make_policy("lqr", baseline_settings(load_experiment(experiment)))
    try:
        for seed in range(10):  # pole mass and length drawn per episode, theta measured with noise
            trace = run_episode(env, policy, seed, None)
            assert not trace.terminated, f"seed {seed}: the pole fell or the cart left the track"
            assert len(trace.time_s) - 1 == 500  # 10 s at 50 Hz
            assert np.max(np.abs(trace.signals["theta"])) < 0.1
    finally:
        env.close()


def test_lqr_tracks_the_dc_motor_speed_within_one_rad_per_second() -> None:
    experiment = example_experiment("dcmotor_tracking")
    env = FmuEnv(experiment)
    policy = make_policy("lqr", baseline_settings(load_experiment(experiment)))
    try:
        for scenario in ("step_up", "step_load", "heavy_load"):  # load steps: the integral removes the offset
            for seed in range(3):
                trace = run_episode(env, policy, seed, scenario)
                error = trace.signals["omega_ref"] - trace.signals["omega"]
                last = error[-30:]  # the last 0.3 s, after every step and load change
                assert abs(float(np.mean(last))) < 1.0, (scenario, seed, float(np.mean(last)))
                assert not trace.terminated
    finally:
        env.close()


def test_lqr_with_preview_keeps_the_car_on_held_out_roads(vehicle: FmuEnv) -> None:
    settings = baseline_settings(vehicle.task.experiment)
    policy = make_policy("lqr", settings)
    for scenario in ("mountain", "country"):
        for seed in range(2):
            trace = run_episode(vehicle, policy, seed, scenario)
            assert not trace.terminated
            assert np.max(np.abs(trace.signals["lateral_error"])) < 0.6


def controllers(design: dict[str, Any], vehicle: FmuEnv) -> tuple[ModelBased, ModelBased]:
    lqr, mpc = ModelBased("lqr", design, "lqr"), ModelBased("mpc", design, "mpc")
    for policy in (lqr, mpc):
        policy.reset(vehicle.task, 0)
    return lqr, mpc


def test_unconstrained_mpc_is_the_lqr_with_preview(vehicle: FmuEnv) -> None:
    """With the Riccati solution as terminal weight and no active limits, the QP's first move is
    the closed-form preview law: two independent computations of the same optimum."""
    design = {**VEHICLE_DESIGN, "horizon": 25, "limits": {"steer_cmd": [-10.0, 10.0]}}
    lqr, mpc = controllers(design, vehicle)
    rng = np.random.default_rng(1)
    for _ in range(20):
        signals = {
            "lateral_error": rng.normal(0, 0.5), "heading_error": rng.normal(0, 0.05),
            "yaw_rate": rng.normal(0, 0.1), "steer_angle": rng.normal(0, 0.05),
            "curvature": rng.normal(0, 0.02),
            "kappa_ahead_05": rng.normal(0, 0.02), "kappa_ahead_10": rng.normal(0, 0.02), "lateral_ref": 0.0,
        }  # fmt: skip
        u_lqr = lqr.controller.control(signals)
        u_mpc = mpc.controller.control(signals)
        np.testing.assert_allclose(u_mpc, u_lqr, atol=1e-5)
    assert mpc.controller.failures == 0


def test_mpc_respects_input_and_rate_limits(vehicle: FmuEnv) -> None:
    design = {
        **VEHICLE_DESIGN,
        "horizon": 10,
        "limits": {"steer_cmd": [-0.04, 0.04]},
        "rate_limits": {"steer_cmd": 0.2},
    }
    policy = ModelBased("mpc", design, "mpc")
    trace = run_episode(vehicle, policy, 0, "hairpin")  # the hairpin needs more than 0.04 rad
    u = trace.inputs["steer_cmd"]
    assert np.max(np.abs(u)) <= 0.04 + 1e-6
    assert np.max(np.abs(u)) > 0.039  # the limit is reached, so it is active
    assert np.max(np.abs(np.diff(u))) <= 0.2 * 0.05 + 1e-5
    assert np.max(np.abs(np.diff(u))) > 0.2 * 0.05 - 1e-4  # and the rate limit too
    assert policy.controller.failures == 0


def test_residual_over_lqr_with_zero_action_is_the_lqr(vehicle: FmuEnv) -> None:
    settings = baseline_settings(vehicle.task.experiment)
    reference = run_episode(vehicle, make_policy("lqr", settings), 4, "slalom")
    wrapped = ResidualWrapper(vehicle, {"baseline": "lqr", "config": settings["lqr"], "scale": 0.1})
    wrapped.reset(seed=4, options={"scenario": "slalom"})
    applied = []
    while True:
        _, _, terminated, truncated, _ = wrapped.step(np.zeros(1, dtype=np.float32))
        applied.append(vehicle.task.applied_inputs[0])
        if terminated or truncated:
            break
    np.testing.assert_allclose(applied, reference.inputs["steer_cmd"], atol=1e-7)


def test_design_errors_name_what_is_wrong(vehicle: FmuEnv) -> None:
    with pytest.raises(ConfigError, match="'wheel_speed'"):
        ModelBased("lqr", {**VEHICLE_DESIGN, "measured": ["wheel_speed"]}, "lqr").reset(vehicle.task, 0)
    with pytest.raises(ConfigError, match="not action inputs"):
        ModelBased("lqr", {**VEHICLE_DESIGN, "inputs": ["v_x"]}, "lqr").reset(vehicle.task, 0)
    with pytest.raises(ValueError, match="integral"):
        ControlDesign.model_validate({**VEHICLE_DESIGN, "integral": {"heading_error": 1.0}})
    with pytest.raises(ValueError, match="preview"):
        ControlDesign.model_validate({**VEHICLE_DESIGN, "disturbances": {}})


def test_lqr_keeps_its_command_within_the_rate_limit_and_counts_the_samples(vehicle: FmuEnv) -> None:
    free = run_episode(vehicle, ModelBased("lqr", VEHICLE_DESIGN, "lqr"), 0, "hairpin")
    dt = 0.05
    assert np.max(np.abs(np.diff(free.inputs["steer_cmd"]))) > 0.2 * dt  # the limit below binds
    policy = ModelBased("lqr", {**VEHICLE_DESIGN, "rate_limits": {"steer_cmd": 0.2}}, "lqr")
    trace = run_episode(vehicle, policy, 0, "hairpin")
    u = trace.inputs["steer_cmd"]
    assert np.max(np.abs(np.diff(u))) <= 0.2 * dt * (1 + 1e-5)  # the action is float32 on its way
    assert trace.extra["rate_limited"] > 0
    assert "solver_fallbacks" not in trace.extra  # an lqr has no solver


def test_mpc_reports_its_solver_fallbacks_per_episode(vehicle: FmuEnv) -> None:
    design = {**VEHICLE_DESIGN, "horizon": 10, "rate_limits": {"steer_cmd": 0.8}}
    policy = ModelBased("mpc", design, "mpc")
    trace = run_episode(vehicle, policy, 0, "s_bend")
    assert trace.extra["solver_fallbacks"] == policy.controller.failures  # first episode: all of them
    assert "rate_limited" in trace.extra


@pytest.fixture(scope="module")
def vehicle_accel(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The showcase with the lateral acceleration observed too (so that the trace holds it)."""
    import yaml

    data = yaml.safe_load(example_experiment("vehicle_path").read_text())
    data.pop("versions", None)
    data["observations"]["outputs"].append("lateral_accel")
    data["observations"]["scale"]["lateral_accel"] = [-10.0, 10.0]
    path = tmp_path_factory.mktemp("accel") / "vehicle.yaml"
    path.write_text(yaml.safe_dump(data))
    env = FmuEnv(load_experiment(path))
    yield env
    env.close()


def test_mpc_keeps_the_lateral_acceleration_within_its_output_limits(vehicle_accel: FmuEnv) -> None:
    """A grip limit as an output limit: the unconstrained mpc exceeds 3 m/s^2 on the hairpin, the
    constrained one plans within it (soft: the plant is not the linear model, so a small overshoot)."""
    vehicle = vehicle_accel
    design = {**VEHICLE_DESIGN, "horizon": 15, "rate_limits": {"steer_cmd": 0.6}}
    free = run_episode(vehicle, ModelBased("mpc", design, "mpc"), 0, "hairpin")
    assert np.max(np.abs(free.signals["lateral_accel"])) > 4.0
    limited = {**design, "output_limits": {"lateral_accel": [-3.0, 3.0]}}
    policy = ModelBased("mpc", limited, "mpc")
    trace = run_episode(vehicle, policy, 0, "hairpin")
    assert np.max(np.abs(trace.signals["lateral_accel"])) < 3.3
    assert policy.controller.failures == 0


def test_output_limits_need_the_mpc(vehicle: FmuEnv) -> None:
    with pytest.raises(ConfigError, match=r"output_limits .*use type: mpc"):
        ModelBased("lqr", {**VEHICLE_DESIGN, "output_limits": {"lateral_accel": [-3.0, 3.0]}}, "lqr").reset(
            vehicle.task, 0
        )


def test_unconstrained_scheduled_mpc_is_the_scheduled_lqr_between_points(vehicle: FmuEnv) -> None:
    """Between two schedule points the lqr blends its gains; the mpc blends the first moves of its
    two neighbours' plans, which without active limits are those gains' laws: the same command.
    (An mpc planning on the nearest point's model alone is off between points.)"""
    design = {
        **VEHICLE_DESIGN,
        "horizon": 25,
        "limits": {"steer_cmd": [-10.0, 10.0]},
        "schedule": {"input": "v_x", "signal": "speed", "points": [10.0, 20.0]},
    }
    lqr, mpc = controllers(design, vehicle)
    rng = np.random.default_rng(2)
    for speed in (10.0, 12.0, 14.9, 15.1, 18.0, 20.0):
        signals = {
            "lateral_error": rng.normal(0, 0.5), "heading_error": rng.normal(0, 0.05),
            "yaw_rate": rng.normal(0, 0.1), "steer_angle": rng.normal(0, 0.05),
            "curvature": rng.normal(0, 0.02), "speed": speed,
            "kappa_ahead_05": rng.normal(0, 0.02), "kappa_ahead_10": rng.normal(0, 0.02), "lateral_ref": 0.0,
        }  # fmt: skip
        np.testing.assert_allclose(
            mpc.controller.control(signals), lqr.controller.control(signals), atol=1e-5
        )
    assert mpc.controller.failures == 0
