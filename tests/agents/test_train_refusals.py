"""``train`` refuses what it cannot train, and a run that does not finish says so in run.json and
to ``evaluate``."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from rewards_for_tests import _Counter

from agents.evaluate import evaluate
from agents.train import train
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment

CARTPOLE = example_experiment("cartpole_balance")
SMALL = {
    "timesteps": 512,
    "n_envs": 1,
    "eval_every": 100_000,
    "hyperparams": {"n_steps": 64, "batch_size": 64},
}
ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}


def _changed(tmp_path: Path, **sections: Any) -> Path:
    data = yaml.safe_load(CARTPOLE.read_text())
    data.pop("versions")
    data.update(sections)
    path = tmp_path / "experiment.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("sections", "expected"),
    [
        (
            {"actions": {"inputs": []}},
            "has no actions (actions.inputs is empty), so there is nothing for an agent to learn; "
            "add an FMU input or a tunable parameter to actions.inputs",
        ),
        ({"observations": {"outputs": []}}, "observations: observe at least one output, reference or error"),
    ],
)
def test_train_refuses_an_experiment_it_cannot_train_with_exit_2(
    tmp_path: Path, sections: dict[str, Any], expected: str
) -> None:
    path = _changed(tmp_path, **sections)
    run_dir = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "train", str(path), "--run-dir", str(run_dir), "--no-progress"],
        capture_output=True, text=True, env=ENV, timeout=300, check=False,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr[-2000:]
    message = " ".join(result.stderr.split())
    assert expected in message and "Traceback" not in result.stderr
    assert not run_dir.exists()  # nothing half made


def test_a_crashed_run_is_marked_failed_and_evaluate_says_so(tmp_path: Path) -> None:
    _Counter.calls = 0
    path = _changed(tmp_path, reward={"callable": "rewards_for_tests:fails_after_200"})
    run = tmp_path / "run"
    with pytest.raises(RuntimeError, match="the reward broke"):
        train(path, overrides=SMALL, run_dir=run, progress=False)
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "failed" and "the reward broke at its 201st call" in info["error"]
    with pytest.raises(ConfigError, match=r"the training of run run failed \(.*the reward broke"):
        evaluate([str(run)], path, episodes=1)


def test_an_interrupted_run_is_marked_and_evaluate_warns(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    _Counter.calls = 0
    path = _changed(tmp_path, reward={"callable": "rewards_for_tests:interrupts_after_200"})
    run = tmp_path / "run"
    train(path, overrides=SMALL, run_dir=run, progress=False)
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "interrupted" and info["timesteps"] < 512
    _Counter.calls = -(10**9)  # evaluation runs normally
    with caplog.at_level(logging.WARNING):
        rows = evaluate([str(run)], path, episodes=1).rows
    assert rows and "was interrupted after" in caplog.text and "only partly trained" in caplog.text
