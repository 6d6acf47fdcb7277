"""Every metric against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.metrics import (
    MetricSpec,
    Trace,
    compute,
    constraint_metrics,
    effort_metrics,
    held_iae,
    step_response,
    success,
    tracking_metrics,
)


def test_tracking_metrics_by_hand() -> None:
    error = np.array([1.0, -2.0, 0.5, 0.0])
    t = np.array([0.1, 0.2, 0.3, 0.4])
    m = tracking_metrics(error, t, dt=0.1)
    assert m["iae"] == pytest.approx((1 + 2 + 0.5 + 0) * 0.1)
    assert m["ise"] == pytest.approx((1 + 4 + 0.25 + 0) * 0.1)
    assert m["itae"] == pytest.approx((0 * 1 + 0.1 * 2 + 0.2 * 0.5 + 0.3 * 0) * 0.1)
    assert m["rmse"] == pytest.approx(math.sqrt((1 + 4 + 0.25) / 4))
    assert m["max_abs_error"] == 2.0


def test_step_response_overshoot_rise_settling_steady_state() -> None:
    t = np.arange(11) * 0.1
    reference = np.array([0, 0, 10, 10, 10, 10, 10, 10, 10, 10, 10], dtype=float)
    output = np.array([0, 0, 0, 5, 9.5, 12, 10.5, 10.1, 10.0, 10.0, 10.0])
    m = step_response(output, reference, t, band=0.02, tail=0.2)
    assert m["overshoot_pct"] == pytest.approx(20.0)  # peak 12 on a 0 -> 10 step
    # after the step (index 2 = t 0): 10 % reached at index 3 (t 0.1), 90 % at index 4 (t 0.2)
    assert m["rise_time_s"] == pytest.approx(0.1)
    # outside +-0.2 until index 6 (10.5); inside from index 7 (10.1): t = 0.5 after the step
    assert m["settling_time_s"] == pytest.approx(0.5)
    assert m["steady_state_error"] == pytest.approx(0.0)
    # a constant reference: the step is from the initial output (1) to the reference (2)
    stuck = step_response(np.ones(5), np.full(5, 2.0), t[:5])
    assert stuck["overshoot_pct"] == 0.0 and stuck["steady_state_error"] == pytest.approx(1.0)
    assert math.isnan(stuck["rise_time_s"]) and math.isnan(stuck["settling_time_s"])
    same = step_response(np.full(5, 2.0), np.full(5, 2.0), t[:5])
    assert math.isnan(same["overshoot_pct"])  # no step at all
    t50 = np.arange(50) * 0.1
    moving = step_response(np.zeros(50), np.sin(t50), t50)
    assert math.isnan(moving["overshoot_pct"]) and math.isnan(moving["settling_time_s"])


def test_effort_and_constraints() -> None:
    u = np.array([1.0, -2.0, 2.0])
    assert effort_metrics(u) == {"effort_abs": 5.0, "effort_sq": 9.0, "total_variation": 7.0}
    v = np.array([0.0, 3.0, -4.0, 1.0])
    assert constraint_metrics(v, -1.0, 2.0, 0.5) == {"violations": 2, "violation_time_s": 1.0}
    assert constraint_metrics(v, None, 2.0, 0.5)["violations"] == 1


def test_compute_from_a_trace_with_success_and_user_metric() -> None:
    t = np.array([0.0, 0.1, 0.2, 0.3])
    trace = Trace(
        time_s=t,
        signals={"y": np.array([0.0, 1.0, 2.0, 2.0]), "r": np.array([2.0, 2.0, 2.0, 2.0])},
        inputs={"u": np.array([3.0, 1.0, 0.0])},
        rewards=np.array([-1.0, -0.5, 0.0]),
        reason="time",
        terminated=False,
    )

    def peak(tr: Trace) -> float:
        return float(tr.signals["y"].max())

    spec = MetricSpec(
        tracking=[("y", "r")],
        effort=["u"],
        constraints={"y": (None, 1.5)},
        success="episode_return > -2 and y_rmse < 1",
        user=[peak],
    )
    row = compute(trace, spec)
    assert row["return"] == -1.5 and row["length"] == 3 and row["reason"] == "time"
    assert row["y.iae"] == pytest.approx((1 + 0 + 0) * 0.1)  # errors after each step: 1, 0, 0
    assert row["y.rmse"] == pytest.approx(math.sqrt(1 / 3))
    assert row["u.effort_sq"] == 10.0 and row["y.violations"] == 2
    assert row["peak"] == 2.0 and row["success"] is True


def test_held_iae_charges_the_last_error_until_the_episode_would_have_ended() -> None:
    error = np.array([0.5, -1.0, 4.2])  # three samples of 0.1 s, then off the envelope at 0.3 s
    assert held_iae(error, 0.1, 1.0) == pytest.approx((0.5 + 1.0 + 4.2) * 0.1 + 4.2 * 0.7)
    assert held_iae(error, 0.1, 0.3) == pytest.approx((0.5 + 1.0 + 4.2) * 0.1)  # ran to the end
    assert math.isnan(held_iae(np.array([]), 0.1, 1.0))


def test_compute_gives_held_iae_with_the_scenarios_own_duration() -> None:
    trace = Trace(
        time_s=np.array([0.0, 0.1, 0.2]),
        signals={"y": np.array([0.0, 1.0, 3.0]), "r": np.zeros(3)},
        inputs={"u": np.zeros(2)},
        rewards=np.zeros(2),
        reason="bounds",
        terminated=True,
        scenario="short",
    )
    spec = MetricSpec(tracking=[("y", "r")], duration_s=2.0, scenario_durations={"short": 1.0})
    row = compute(trace, spec)
    assert row["y.iae"] == pytest.approx((1 + 3) * 0.1)
    assert row["y.iae_held"] == pytest.approx((1 + 3) * 0.1 + 3 * 0.8)
    assert "y.iae_held" not in compute(trace, MetricSpec(tracking=[("y", "r")]))


def test_success_condition_uses_the_safe_evaluator() -> None:
    assert success("episode_return >= 475", {"return": 480.0}) is True
    assert success("episode_return >= 475 and not terminated", {"return": 480.0, "terminated": True}) is False
    with pytest.raises(Exception, match=r"__import__|not allowed|unknown"):
        success("__import__('os')", {"return": 1.0})
