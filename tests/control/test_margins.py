"""Stability margins of a design as it runs, checked on the real cart-pole FMU.

The margins say between which factors ``g`` on the controller's output the loop (the LQR with its
Kalman filter, broken at the plant input) stays stable. The test closes the loop around the FMU
with the output scaled by ``g`` a little inside and a little outside that interval, from a small
tilt where the pole is nearly linear: inside it the pole settles, outside it the tilt grows.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from agents.evaluate import baseline_settings
from agents.policies import ModelBased, make_policy
from bridge.control.margins import margins
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment


@pytest.fixture(scope="module")
def cartpole(tmp_path_factory: pytest.TempPathFactory) -> Any:
    data = yaml.safe_load(Path(example_experiment("cartpole_continuous")).read_text())
    data.pop("versions", None)
    data["randomization"] = {"parameters": {"theta0": {"uniform": [0.01, 0.01]}}}  # nominal pole, fixed tilt
    data.pop("noise")
    data["termination"] = {"bounds": {"theta": [-1.0, 1.0]}}
    data["model"]["episode_duration"] = 20.0
    data["actions"]["low"], data["actions"]["high"] = {"force": -1e4}, {"force": 1e4}  # no saturation
    path = tmp_path_factory.mktemp("margins") / "cartpole.yaml"
    path.write_text(yaml.safe_dump(data))
    experiment = load_experiment(path)
    env = FmuEnv(experiment)
    policy = make_policy("lqr", baseline_settings(experiment))
    policy.reset(env.unwrapped.task, 0)
    yield env, policy
    env.close()


def _final_tilt(env: FmuEnv, policy: ModelBased, gain: float) -> float:
    """|theta| over the last second with the controller's force scaled by ``gain`` (or the tilt
    when the pole left the +-1 rad window)."""
    env.reset(seed=0)
    policy.reset(env.unwrapped.task, 0)
    task = env.unwrapped.task
    thetas = []
    while True:
        (force,) = policy.controller.control(task.controller_signals())
        _, _, terminated, truncated, _ = env.step(task.action_for_inputs([gain * force]))
        thetas.append(abs(task.signal_dict()["theta"]))
        if terminated or truncated:
            break
    return max(thetas[-50:])


def test_the_gain_interval_predicts_where_the_real_loop_is_stable(cartpole: Any) -> None:
    env, policy = cartpole
    (design,) = policy.controller.designs
    m = margins(design)
    assert m.stable and 0 < m.gain_low < 1 < m.gain_high < np.inf  # an unstable plant: a lower margin too
    assert 20 < m.phase_deg < 90 and 0 < m.stability <= 1
    assert _final_tilt(env, policy, 1.0) < 1e-3
    assert _final_tilt(env, policy, 1.15 * m.gain_low) < 5e-3
    assert _final_tilt(env, policy, 0.85 * m.gain_low) > 0.05
    assert _final_tilt(env, policy, 0.9 * m.gain_high) < 5e-3
    assert _final_tilt(env, policy, 1.1 * m.gain_high) > 0.05


def test_the_evaluation_report_lists_the_margins_of_its_model_based_baselines(tmp_path: Path) -> None:
    import json

    from agents.evaluate import evaluate
    from agents.report import write

    path = Path(example_experiment("dcmotor_tracking"))
    result = evaluate(["lqr", "pid"], path, episodes=2, batch=True, scenarios=["step_up"])
    paths = write(result, tmp_path, "margins", experiment=load_experiment(path))
    rows = json.loads(paths["json"].read_text())["margins"]
    assert [r["baseline"] for r in rows] == ["lqr"]  # the pid has no linear design
    assert rows[0]["closed_loop_radius"] < 1.0 and rows[0]["phase_margin_deg"] > 0
    assert "## Stability margins of the model-based designs" in paths["report"].read_text()
