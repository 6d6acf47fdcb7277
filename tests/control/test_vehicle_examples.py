"""The vehicle examples' baselines against the FMU they control: the actuator's rate limit in every
linear design, and the worn-actuator family really lying outside the designs' model."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fmpy import read_model_description

from agents.evaluate import baseline_settings, run_episode
from agents.policies import make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.experiment import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.models import example_fmu


def fmu_defaults() -> dict[str, float]:
    """The vehicle FMU's parameter start values, read from its model description by FMPy."""
    description = read_model_description(str(example_fmu("vehicle", "2.0", "me")))
    return {v.name: float(v.start) for v in description.modelVariables if v.causality == "parameter"}


@pytest.mark.parametrize("example", ["vehicle_path", "vehicle_worn"])
def test_the_mpc_plans_with_the_actuators_steering_rate(example: str) -> None:
    """The designs' rate limits are the actuator's (the FMU's steer_rate_max), never a faster one;
    the tuned lqr goes without (unstable with it: docs/control.md)."""
    experiment = load_experiment(example_experiment(example))
    rate = fmu_defaults()["steer_rate_max"]
    settings = baseline_settings(experiment)
    assert settings["mpc"]["design"]["rate_limits"] == {"steer_cmd": rate}
    assert settings["lqr_soft"]["design"]["rate_limits"] == {"steer_cmd": rate}
    for name, baseline in settings.items():
        given = baseline.get("design", {}).get("rate_limits") or {}
        assert given in ({}, {"steer_cmd": rate}), name


def test_the_worn_family_lies_outside_the_designs_model() -> None:
    """The designs linearise the FMU at its defaults; the worn family draws every episode's
    actuator and mass beyond them, so the model-based baselines' model is wrong."""
    experiment = load_experiment(example_experiment("vehicle_worn"))
    nominal = fmu_defaults()
    drawn = experiment.randomization.parameters
    for name in ("steer_tau", "m"):
        low = drawn[name].uniform
        assert low is not None and low[0] > nominal[name], name  # slower, heavier: always
    rate = drawn["steer_rate_max"].uniform
    assert rate is not None and rate[1] < nominal["steer_rate_max"]  # rate-limited harder: always
    for baseline in baseline_settings(experiment).values():
        assert "operating_point" not in baseline.get("design", {})  # designed at the defaults


@pytest.fixture(scope="module")
def worn() -> Any:
    env = FmuEnv(example_experiment("vehicle_worn"))
    yield env
    env.close()


@pytest.mark.parametrize("baseline", ["lqr", "mpc", "lqr_soft", "pid"])
def test_the_worn_family_baselines_run_a_held_out_episode(worn: FmuEnv, baseline: str) -> None:
    settings = baseline_settings(worn.task.experiment)
    trace = run_episode(worn, make_policy(baseline, settings), 0, "country")
    assert trace.scenario == "country"
    steer = np.asarray(trace.inputs["steer_cmd"])
    assert len(steer) > 20 and np.all(np.isfinite(steer)) and np.max(np.abs(steer)) > 0.0
