"""``fmu-bridge agent check``: an evaluation recording replayed through the deployed runtimes (torch,
ONNX, policy FMU); a permuted or rescaled deployment mapping fails."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from agents.check import check_deployment
from agents.evaluate import evaluate
from bridge.experiment.examples import example_experiment

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]  # the balancer trains for minutes
CARTPOLE = example_experiment("cartpole_balance")


@pytest.fixture(scope="module")
def deployment(balancer: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A copy of the balancer's run with its ONNX graph and policy FMU, and one recorded evaluation."""
    from agents.export.onnx import export_onnx
    from agents.export.policy_fmu import export_fmu

    root = tmp_path_factory.mktemp("check")
    run = root / "ppo"
    shutil.copytree(balancer, run)
    export_onnx(run)
    export_fmu(run)
    evaluate([str(run)], CARTPOLE, episodes=2, record_dir=root / "recordings")
    (recording,) = sorted((root / "recordings").rglob("*.mcap"))
    return run, recording


@pytest.mark.parametrize("runtime", ["torch", "onnx", "fmu"])
def test_the_deployed_runtimes_act_as_recorded(deployment: tuple[Path, Path], runtime: str) -> None:
    run, recording = deployment
    report = check_deployment(run, recording, runtime=runtime)
    assert report.mapping == [] and report.compared >= 100, report
    assert report.max_action_difference == 0.0 and report.differing == 0, report
    assert 0 < report.latency_us["p50"] <= report.latency_us["p99"] <= report.latency_us["max"]
    assert report.ok


def _variant(run: Path, tmp_path: Path, change: dict[str, object]) -> Path:
    data = yaml.safe_load((run / "experiment.yaml").read_text())
    assert data["model"]["fmu"] == "example:cartpole"  # found from any folder
    data["observations"].update(change)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("change", "found"),
    [
        ({"outputs": ["theta", "x", "x_dot", "theta_dot"]}, "order differs"),
        (
            {"scale": {"x": [-2.4, 2.4], "x_dot": [-3, 3], "theta": [-0.2, 0.2], "theta_dot": [-3, 3]}},
            "scale",
        ),
    ],
    ids=["permuted", "rescaled"],
)
def test_a_permuted_or_rescaled_mapping_fails(
    deployment: tuple[Path, Path], tmp_path: Path, change: dict[str, object], found: str
) -> None:
    run, recording = deployment
    config = _variant(run, tmp_path, change)
    report = check_deployment(run, recording, config=config)
    assert not report.ok
    assert any(found in problem for problem in report.mapping), report.mapping
    assert report.max_action_difference > 0  # and the actions show it
    cmd = [sys.executable, "-m", "bridge.cli", "agent", "check", str(run), "--recording", str(recording)]
    result = subprocess.run(
        [*cmd, "--config", str(config)], capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "check failed" in result.stdout and found.split(maxsplit=1)[0] in result.stdout
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0 and "check passed" in result.stdout, result.stdout + result.stderr
