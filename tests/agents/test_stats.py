"""Evaluation statistics: bootstrap intervals and paired differences, against an independent bootstrap."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats as scipy_stats
from typer.testing import CliRunner

from agents.stats import bootstrap_interval, describe, paired_differences, verdict
from bridge.cli.main import _load_plugins, app
from bridge.errors import ConfigError

_load_plugins()  # the agents' commands (evaluate) join the app as the installed command has them


def _scipy_interval(values: np.ndarray, statistic: str) -> tuple[float, float]:
    fn = np.mean if statistic == "mean" else np.median
    res = scipy_stats.bootstrap(
        (values,), fn, n_resamples=20_000, confidence_level=0.95, method="percentile", random_state=123
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


@pytest.mark.parametrize("statistic", ["mean", "median"])
def test_the_interval_equals_an_independent_percentile_bootstrap(statistic: str) -> None:
    values = np.random.default_rng(4).normal(10.0, 3.0, size=25)
    low, high = bootstrap_interval(values, statistic)
    ref_low, ref_high = _scipy_interval(values, statistic)
    width = ref_high - ref_low
    assert low == pytest.approx(ref_low, abs=0.08 * width)  # two Monte Carlo draws of one interval
    assert high == pytest.approx(ref_high, abs=0.08 * width)
    assert low < fn_of(values, statistic) < high


def fn_of(values: np.ndarray, statistic: str) -> float:
    return float(np.mean(values) if statistic == "mean" else np.median(values))


def test_one_value_has_no_interval_and_constants_have_a_point() -> None:
    assert all(math.isnan(v) for v in bootstrap_interval([3.0]))
    assert bootstrap_interval([2.0, 2.0, 2.0]) == (2.0, 2.0)
    assert math.isnan(describe([1.0])["std"])


def test_verdicts_follow_the_interval_and_the_metric_direction() -> None:
    assert verdict(0.5, 2.0, higher_better=True) == "better"
    assert verdict(0.5, 2.0, higher_better=False) == "worse"  # e.g. an rmse that grew
    assert verdict(-1.0, 2.0, higher_better=True) == "no difference shown"
    assert verdict(math.nan, math.nan, higher_better=True) == "n/a"


def test_paired_differences_pair_by_scenario_and_seed() -> None:
    rows = [
        {"agent": a, "scenario": sc, "seed": seed, "return": base + (2.0 if a == "b" else 0.0) + seed}
        for a in ("a", "b")
        for sc, base in (("x", 0.0), ("y", 10.0))
        for seed in range(4)
    ]
    rows.append({"agent": "b", "scenario": "x", "seed": 99, "return": -1e9})  # no partner: left out
    out = {r["scenario"]: r for r in paired_differences(rows, "a")}
    assert set(out) == {"x", "y", "all"}
    assert out["x"]["episodes"] == 4 and out["all"]["episodes"] == 8
    assert out["x"]["difference"] == 2.0 and out["x"]["wins"] == 4 and out["x"]["losses"] == 0
    assert (out["x"]["low"], out["x"]["high"]) == (2.0, 2.0)
    assert out["x"]["verdict"] == "better"


def test_a_lower_is_better_metric_counts_a_smaller_value_as_a_win() -> None:
    rows = [
        {"agent": a, "scenario": "s", "seed": i, "x.rmse": v}
        for i in range(3)
        for a, v in (("a", 1.0), ("b", 0.5))
    ]
    (row,) = paired_differences(rows, "a", "x.rmse")
    assert row["wins"] == 3 and row["difference"] == -0.5 and row["verdict"] == "better"


@pytest.fixture
def noisy_motor(tmp_path: Path) -> Path:
    data = {
        "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 0.2},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega"], "references": ["omega_ref"]},
        "reward": {"terms": [{"tracking": {"output": "omega", "reference": "omega_ref", "norm": "abs"}}]},
        "scenarios": {"hold": {"references": {"omega_ref": 20.0}}},
        "randomization": {"parameters": {"omega0": {"uniform": [-5.0, 5.0]}}},
    }
    path = tmp_path / "motor.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_evaluate_prints_and_writes_intervals_and_paired_differences(
    noisy_motor: Path, tmp_path: Path
) -> None:
    out = tmp_path / "eval"
    result = CliRunner().invoke(
        app,
        ["evaluate", "constant:6", "constant:12", "--config", str(noisy_motor), "--episodes", "12",
         "--no-record", "--out", str(out), "--reference", "constant:6"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "paired by seed" in result.output and "95% CI" in result.output
    data = json.loads((out / "results.json").read_text())
    episodes = data["episodes"]
    ref = {e["seed"]: e["return"] for e in episodes if e["agent"] == "constant:6"}
    other = {e["seed"]: e["return"] for e in episodes if e["agent"] == "constant:12"}
    diff = np.array([other[s] - ref[s] for s in sorted(ref)])
    (pair,) = data["paired"]
    assert pair["episodes"] == 12
    assert pair["difference"] == pytest.approx(float(diff.mean()))
    low, high = _scipy_interval(diff, "mean")
    width = max(high - low, 1e-12)
    assert pair["low"] == pytest.approx(low, abs=0.08 * width)
    assert pair["high"] == pytest.approx(high, abs=0.08 * width)
    assert pair["wins"] + pair["losses"] + pair["ties"] == 12
    spread = {row["agent"]: row for row in data["summary"]}
    returns = np.array([ref[s] for s in sorted(ref)])
    assert spread["constant:6"]["return.median"] == pytest.approx(float(np.median(returns)))
    med_low, med_high = _scipy_interval(returns, "median")
    assert spread["constant:6"]["return.median_low"] == pytest.approx(
        med_low, abs=0.1 * (med_high - med_low) + 1e-9
    )
    report = (out / "report.md").read_text()
    assert "Paired differences of return against constant:6" in report


def test_an_unknown_reference_is_refused_by_name(noisy_motor: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["evaluate", "constant:6", "--config", str(noisy_motor), "--episodes", "2", "--no-record",
         "--out", str(tmp_path / "e"), "--reference", "lqr"],
    )  # fmt: skip
    assert isinstance(result.exception, ConfigError)
    assert "--reference 'lqr' is not one of the evaluated agents ['constant:6']" in str(result.exception)
    assert not (tmp_path / "e").exists()  # refused before any episode ran
