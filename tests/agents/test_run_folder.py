"""A run folder is self-contained: its experiment names the user's FMU by absolute path (or holds a
copy of it), so ``--resume``, ``evaluate`` and ``agent run`` work from any folder, and with a copy
even after the original FMU is gone."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agents.deploy import deployment_experiment
from agents.evaluate import evaluate
from agents.train import train
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.validate import resolve_fmu
from bridge.models import example_fmu

SMALL = {
    "timesteps": 128,
    "n_envs": 1,
    "eval_every": 100_000,
    "hyperparams": {"n_steps": 64, "batch_size": 64},
}


def _project(tmp_path: Path) -> Path:
    """A user's project: their FMU beside their experiment, named relative to it."""
    project = tmp_path / "project"
    (project / "data").mkdir(parents=True)
    shutil.copy(example_fmu("cartpole", "2.0", "cs"), project / "ball.fmu")
    text = example_experiment("cartpole_balance").read_text()
    assert "  fmu: example:cartpole " in text
    path = project / "experiment.yaml"
    path.write_text(text.replace("  fmu: example:cartpole ", "  fmu: ball.fmu ", 1))
    return path


def test_resume_and_evaluate_work_from_any_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _project(tmp_path)
    elsewhere, third = tmp_path / "elsewhere", tmp_path / "third"
    elsewhere.mkdir()
    third.mkdir()
    monkeypatch.chdir(elsewhere)
    first = train(Path("../project/experiment.yaml"), overrides=SMALL, run_dir=Path("runs/r"), progress=False)
    run = (elsewhere / "runs" / "r").resolve()
    copy = run / "experiment.yaml"
    assert load_experiment(copy).model.fmu == str((tmp_path / "project" / "ball.fmu").resolve())
    assert copy.read_text().startswith("# Balance a pole")  # the comments are kept
    monkeypatch.chdir(third)
    second = train(None, overrides={"timesteps": 64}, resume=run, progress=False)
    assert second.timesteps > first.timesteps
    rows = evaluate([str(run)], copy, episodes=1).rows
    assert rows and rows[0]["length"] >= 1
    experiment, used = deployment_experiment(run, None)  # what `agent run RUN` deploys with
    assert used == run / "experiment.yaml"
    assert resolve_fmu(experiment) == (tmp_path / "project" / "ball.fmu").resolve()


def test_a_run_with_a_copy_of_the_fmu_outlives_the_original(tmp_path: Path) -> None:
    experiment = _project(tmp_path)
    run = tmp_path / "runs" / "copied"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    command = [sys.executable, "-m", "bridge.cli", "train", str(experiment), "--run-dir", str(run),
               "--fmu", "copy", "--timesteps", "64", "--n-envs", "1", "--no-progress"]  # fmt: skip
    result = subprocess.run(
        command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert (run / "ball.fmu").is_file() and load_experiment(run / "experiment.yaml").model.fmu == "ball.fmu"
    (tmp_path / "project" / "ball.fmu").unlink()
    other = tmp_path / "other"
    other.mkdir()
    resumed = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "train", "--resume", str(run), "--timesteps", "64",
         "--no-progress"],
        cwd=other, env=env, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert json.loads((run / "run.json").read_text())["resumed"]
