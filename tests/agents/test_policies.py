"""Baselines: PID by hand, fixed and Python policies, the residual combination."""

from __future__ import annotations

import numpy as np
import pytest

from agents.policies import FixedPolicy, Pid, PidSpec, make_policy
from agents.residual import combine
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment


@pytest.fixture(scope="module")
def motor() -> FmuEnv:
    env = FmuEnv(example_experiment("dcmotor_tracking"))
    env.reset(seed=0, options={"scenario": "step_up"})
    yield env
    env.close()


def test_pid_sequence_by_hand(motor: FmuEnv) -> None:
    spec = PidSpec(
        output="omega",
        reference="omega_ref",
        input="voltage",
        kp=2.0,
        ki=10.0,
        kd=0.1,
        limits=(-24.0, 24.0),
        anti_windup="clamp",
    )
    pid = Pid(spec)
    pid.reset(motor.task, 0)
    dt = 0.01
    u1 = pid.control({"omega": 0.0, "omega_ref": 1.0})  # e=1: P 2, I 0 (first step), D 0
    assert u1 == pytest.approx(2.0)
    u2 = pid.control({"omega": 0.5, "omega_ref": 1.0})  # e=0.5: P 1, I 10*1*dt, D 0.1*(0.5-1)/dt
    assert u2 == pytest.approx(1.0 + 10 * 1.0 * dt + 0.1 * (0.5 - 1.0) / dt)
    big = pid.control({"omega": 0.0, "omega_ref": 100.0})
    assert big == 24.0  # saturated
    integral = pid._integral
    pid.control({"omega": 0.0, "omega_ref": 100.0})
    assert pid._integral == integral  # clamp: no windup while saturated in the error's direction


def test_pid_back_calculation_bleeds_the_integrator(motor: FmuEnv) -> None:
    spec = PidSpec(
        output="omega",
        reference="omega_ref",
        input="voltage",
        kp=1.0,
        ki=10.0,
        limits=(-5.0, 5.0),
        anti_windup="back_calculation",
        tracking_time_s=0.05,
    )
    pid = Pid(spec)
    pid.reset(motor.task, 0)
    pid.control({"omega": 0.0, "omega_ref": 10.0})  # u* = 10 -> 5: integral += 1 + (5 - 10) * 0.01 / 0.05
    assert pid._integral == pytest.approx(10 * 10 * 0.01 + (5 - 10) * 0.01 / 0.05)


def test_pid_acts_through_the_action_space(motor: FmuEnv) -> None:
    pid = Pid(PidSpec(output="omega", reference="omega_ref", input="voltage", kp=1.0, limits=(-24, 24)))
    pid.reset(motor.task, 0)
    action = pid.act(None, {"omega": 0.0, "omega_ref": 12.0, "load_torque": 0.0, "voltage": 0.0})
    np.testing.assert_allclose(action, [0.5])  # 12 V of +-24 V


def test_pid_feedforward_adds_gain_times_signal(motor: FmuEnv) -> None:
    spec = PidSpec(
        output="omega",
        reference="omega_ref",
        input="voltage",
        kp=2.0,
        feedforward=0.5,
        feedforward_gains={"omega_ref": 0.25, "load_torque": -3.0},
        limits=(-24.0, 24.0),
    )
    pid = Pid(spec)
    pid.reset(motor.task, 0)
    u = pid.control({"omega": 1.0, "omega_ref": 4.0, "load_torque": 0.2})
    assert u == pytest.approx(0.5 + 0.25 * 4.0 - 3.0 * 0.2 + 2.0 * (4.0 - 1.0))
    saturated = pid.control({"omega": 0.0, "omega_ref": 200.0, "load_torque": 0.0})
    assert saturated == 24.0  # the feed-forward goes through the same limits


def test_pid_feedforward_signal_names_are_checked(motor: FmuEnv) -> None:
    spec = PidSpec(output="omega", reference="omega_ref", input="voltage", feedforward_gains={"kappa": 1.0})
    with pytest.raises(ConfigError, match="feed-forward signal 'kappa' is not a signal"):
        Pid(spec).reset(motor.task, 0)


def test_pid_names_are_checked(motor: FmuEnv) -> None:
    with pytest.raises(ConfigError, match="'speed' is not a signal"):
        Pid(PidSpec(output="speed", reference="omega_ref", input="voltage")).reset(motor.task, 0)


def test_fixed_policies(motor: FmuEnv) -> None:
    zero = FixedPolicy("zero", 0.0)
    zero.reset(motor.task, 0)
    np.testing.assert_allclose(zero.act(None, {}), [0.0])
    constant = make_policy("constant:6", {})
    constant.reset(motor.task, 0)
    np.testing.assert_allclose(constant.act(None, {}), [0.25])
    start = make_policy("start", {})
    start.reset(motor.task, 0)
    declared = [float(motor.task.variables[name].start) for name in motor.task.action_inputs]
    assert start.act(None, {}).physical == declared  # the inputs' start values, applied exactly
    a, b = make_policy("random", {}), make_policy("random", {})
    a.reset(motor.task, 3)
    b.reset(motor.task, 3)
    assert np.array_equal(a.act(None, {}), b.act(None, {}))


def test_residual_adds_to_the_baseline(motor: FmuEnv) -> None:
    pid = Pid(PidSpec(output="omega", reference="omega_ref", input="voltage", kp=1.0, limits=(-24, 24)))
    pid.reset(motor.task, 0)
    signals = {"omega": 0.0, "omega_ref": 6.0, "load_torque": 0.0, "voltage": 0.0}
    action = combine(motor.task, pid, signals, np.array([0.5]), scale=4.0)  # 6 V + 0.5 * 4 V = 8 V
    np.testing.assert_allclose(action, [8.0 / 24.0])


def test_unknown_agent_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="not a model file or run directory"):
        make_policy("no_such_thing", {"pid": {}})


def test_zero_on_a_discrete_space_without_a_zero_level_says_so() -> None:
    """Cart-pole pushes -10 N or +10 N: 'zero' cannot apply 0 N there and must not pretend to."""
    env = FmuEnv(example_experiment("cartpole_balance"))
    try:
        with pytest.raises(
            ConfigError, match=r"no action applying zero input: levels \{'force': \[-10.0, 10.0\]\}"
        ):
            make_policy("zero", {}).reset(env.task, 0)
        push = make_policy("constant:-10", {})
        push.reset(env.task, 0)
        obs, _ = env.reset(seed=0)
        env.step(push.act(obs, env.task.signal_dict()))
        assert env.task.applied_inputs[0] == -10.0
    finally:
        env.close()
