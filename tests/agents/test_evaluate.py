"""Evaluation: a scripted policy whose metrics follow from the analytic DC motor solution."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.linalg import expm

from agents.evaluate import evaluate
from agents.report import summary, write
from bridge.errors import ConfigError

R, L, K, J, B = 1.0, 0.0025, 0.1, 0.01, 1e-4
H, VOLTS, REF, N = 0.01, 12.0, 50.0, 100


def analytic_omega() -> np.ndarray:
    """omega after each of N samples of 12 V from rest (exact zero-order-hold discretisation)."""
    a = np.array([[-R / L, -K / L], [K / J, -B / J]])
    b = np.array([1 / L, 0.0])
    phi = expm(a * H)
    gamma = np.linalg.solve(a, (phi - np.eye(2)) @ b)
    x, out = np.zeros(2), []
    for _ in range(N):
        x = phi @ x + gamma * VOLTS
        out.append(x[1])
    return np.array(out)


@pytest.fixture
def experiment(tmp_path: Path) -> Path:
    data = {
        "model": {"fmu": "example:dcmotor", "step_size": H, "episode_duration": N * H},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega"], "references": ["omega_ref"]},
        "reward": {
            "terms": [
                {"tracking": {"output": "omega", "reference": "omega_ref", "norm": "abs", "scale": 100.0}}
            ]
        },
        "scenarios": {"hold50": {"references": {"omega_ref": REF}}},
        "evaluation": {
            "metrics": {
                "tracking": [["omega", "omega_ref"]],
                "effort": ["voltage"],
                "constraints": {"omega": [None, 40.0]},
                "success": "omega_rmse < 100",
            }
        },
    }
    path = tmp_path / "motor.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_scripted_policy_metrics_match_the_analytic_solution(experiment: Path, tmp_path: Path) -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    result = evaluate(["python:rewards_for_tests:half_voltage", "constant:12"], experiment, episodes=2)
    omega = analytic_omega()
    error = REF - omega
    expected = {
        "return": -np.sum(np.abs(error)) / 100.0,
        "omega.iae": np.sum(np.abs(error)) * H,
        "omega.ise": np.sum(error**2) * H,
        "omega.rmse": math.sqrt(np.mean(error**2)),
        "omega.max_abs_error": np.max(np.abs(error)),
        "voltage.effort_abs": N * VOLTS,
        "voltage.effort_sq": N * VOLTS**2,
        "voltage.total_variation": 0.0,
        "omega.violations": int(np.sum(omega > 40.0)),
    }
    assert len(result.rows) == 4  # 2 agents x 1 scenario x 2 episodes
    for row in result.rows:
        for key, value in expected.items():
            assert row[key] == pytest.approx(value, rel=1e-6, abs=1e-6), key
        assert row["length"] == N and row["reason"] == "time" and row["success"] is True
    paths = write(result, tmp_path / "out", title="motor")
    data = json.loads(paths["json"].read_text())
    assert len(data["episodes"]) == 4 and len(data["summary"]) == 2
    assert "omega.rmse" in paths["csv"].read_text().splitlines()[0]
    assert (tmp_path / "out" / "metrics.png").is_file() and "![metrics](metrics.png)" in paths[
        "report"
    ].read_text()


@pytest.mark.integration
def test_workers_give_the_same_rows_as_one_process(experiment: Path) -> None:
    one = evaluate(["constant:6", "random"], experiment, episodes=2, workers=1, seed=7)
    two = evaluate(["constant:6", "random"], experiment, episodes=2, workers=2, seed=7)
    assert json.dumps(one.rows) == json.dumps(two.rows)  # NaN-aware equality
    means = {row["agent"]: row["return"] for row in summary(one)}
    assert set(means) == {"constant:6", "random"}


def test_every_agent_sees_the_same_seeds(tmp_path: Path) -> None:
    from bridge.experiment.examples import example_experiment

    result = evaluate(["zero", "random"], example_experiment("cartpole_continuous"), episodes=3, seed=11)
    seeds = {(r["agent"], r["episode"]): r["seed"] for r in result.rows}
    assert [seeds[("zero", i)] for i in range(3)] == [seeds[("random", i)] for i in range(3)] == [11, 12, 13]


def test_name_equals_agent_names_an_agent_and_names_must_differ(experiment: Path) -> None:
    named = evaluate(["half=constant:6", "constant:12"], experiment, episodes=1)
    assert {r["agent"] for r in named.rows} == {"half", "constant:12"}
    same = {r["return"] for r in named.rows if r["agent"] == "half"}
    assert same == {r["return"] for r in evaluate(["constant:6"], experiment, episodes=1).rows}
    with pytest.raises(ConfigError, match="distinct names"):
        evaluate(["a=constant:6", "a=constant:12"], experiment, episodes=1)
