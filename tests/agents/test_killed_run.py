"""A training process killed with SIGKILL says nothing; its run is still found ``interrupted``.

A real ``fmu-bridge train`` runs as a subprocess; the test waits (on conditions, never a sleep)
for run.json to say ``running`` and for a checkpoint, kills the process, then asks what a user
would: ``compare``, ``evaluate``, ``agent run``-style loading and ``train --resume``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from agents.checkpoints import save_atomically
from agents.compare import compare_runs
from agents.run_state import read_run, training_alive, training_lock
from agents.train import train
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment
from bridge.experiment.sections import TrainingSection
from tests.conftest import stop_process, wait_until

CARTPOLE = example_experiment("cartpole_balance")
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
EVALUATE = ("--episodes", "1", "--no-record", "--out", "evaluation")  # under the test's folder


def _experiment(tmp_path: Path) -> Path:
    data = yaml.safe_load(CARTPOLE.read_text())
    data.pop("versions")
    data["training"] |= {
        "timesteps": 10_000_000,  # far more than the test lets it run
        "n_envs": 1,
        "checkpoint_every": 256,
        "eval_every": 10_000_000,
        "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
    }
    path = tmp_path / "experiment.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bridge.cli", *args],
        capture_output=True, text=True, env=ENV, cwd=cwd, timeout=600, check=False,
    )  # fmt: skip


def _status(run: Path) -> str:
    file = run / "run.json"
    return str(json.loads(file.read_text()).get("status")) if file.is_file() else ""


@pytest.mark.slow
def test_a_killed_training_is_reported_interrupted_and_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    experiment, run = _experiment(tmp_path), tmp_path / "run"
    log = (tmp_path / "train.log").open("w")
    command = ["train", str(experiment), "--run-dir", str(run), "--no-progress"]
    trainer = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *command],
        stdout=log, stderr=subprocess.STDOUT, text=True, env=ENV, cwd=tmp_path,
    )  # fmt: skip
    try:
        wait_until(
            lambda: _status(run) == "running" and any((run / "checkpoints").glob("*_steps.zip")),
            300,
            "the training running with a checkpoint saved",
        )
        assert training_alive(run) and read_run(run)["status"] == "running"
        refused = _cli(tmp_path, "train", "--resume", str(run), "--no-progress")
        assert refused.returncode == 2, refused.stderr[-2000:]
        assert "is being trained by another process (pid" in " ".join(refused.stderr.split())
        trainer.send_signal(signal.SIGKILL)
        trainer.wait(timeout=60)
    finally:
        stop_process(trainer, timeout_s=10)
        log.close()
    assert trainer.returncode == -signal.SIGKILL, (tmp_path / "train.log").read_text()[-3000:]
    assert _status(run) == "running"  # what the killed process left in run.json
    assert not (run / "model.zip").exists()  # it never got to save its final model

    assert not training_alive(run)
    info = read_run(run)
    assert info["status"] == "interrupted" and "killed or crashed" in info["status_detail"]
    assert compare_runs([run])[0][0]["status"] == "interrupted"
    shown = _cli(tmp_path, "evaluate", str(run), "--config", str(experiment), *EVALUATE)
    assert shown.returncode == 2, shown.stderr[-2000:]
    message = " ".join(shown.stderr.split())
    assert "run run was interrupted before it saved a model" in message
    assert "killed or crashed" in message and "train --resume" in message

    resumed = _cli(tmp_path, "train", "--resume", str(run), "--timesteps", "128", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "resuming from its checkpoint at" in " ".join(resumed.stderr.split())
    assert _status(run) == "done" and (run / "model.zip").is_file()
    after = _cli(tmp_path, "evaluate", str(run), "--config", str(experiment), *EVALUATE)
    assert after.returncode == 0, after.stderr[-2000:]
    assert "interrupted" not in after.stderr


def test_the_lock_is_what_tells_a_live_training_from_a_dead_one(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"status": "running"}))
    assert read_run(run)["status"] == "interrupted"  # no lock file: no process trains it
    with training_lock(run):
        assert training_alive(run) and read_run(run)["status"] == "running"
        with (
            pytest.raises(ConfigError, match=r"is being trained by another process \(pid \d+\)"),
            training_lock(run),
        ):
            pass
    assert not training_alive(run) and read_run(run)["status_detail"].endswith("(killed or crashed)")


def test_resuming_a_run_that_died_before_its_first_checkpoint_says_so(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"status": "running", "version": None}))
    with pytest.raises(ConfigError, match=r"has no model\.zip and no checkpoint to continue from"):
        train(None, resume=run)


@pytest.mark.slow
def test_sigterm_saves_the_model_and_records_interrupted_and_run_json_always_has_a_status(
    tmp_path: Path,
) -> None:
    """``kill`` (SIGTERM) of ``train`` once saved nothing and left ``status: running``; a run killed
    before its first step had no status at all."""
    experiment, run = _experiment(tmp_path), tmp_path / "run"
    log = (tmp_path / "train.log").open("w")
    trainer = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "train", str(experiment), "--run-dir", str(run),
         "--no-progress"],
        stdout=log, stderr=subprocess.STDOUT, text=True, env=ENV, cwd=tmp_path,
    )  # fmt: skip
    try:
        wait_until((run / "run.json").is_file, 300, "run.json written")
        assert _status(run) in ("starting", "running")  # a status from the first write on
        wait_until(lambda: _status(run) == "running", 300, "the training running")
        trainer.send_signal(signal.SIGTERM)
        trainer.wait(timeout=120)
    finally:
        stop_process(trainer, timeout_s=10)
        log.close()
    assert _status(run) == "interrupted", (tmp_path / "train.log").read_text()[-3000:]
    assert (run / "model.zip").is_file() and not list(run.glob(".*.tmp*"))
    resumed = _cli(tmp_path, "train", "--resume", str(run), "--timesteps", "128", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert _status(run) == "done"


@pytest.mark.slow
def test_resume_falls_back_to_the_newest_checkpoint_that_loads(tmp_path: Path) -> None:
    """A checkpoint cut by a kill (or a cut model.zip) once blocked ``--resume`` with an intact
    older one beside it; now the newest one that loads is used, and the others are named."""
    data = yaml.safe_load(_experiment(tmp_path).read_text())
    data["training"] |= {"timesteps": 640, "eval_every": 100_000}
    data["training"].pop("checkpoint_every")  # scaled to the run: a tenth of it, 64 steps
    experiment = tmp_path / "short.yaml"
    experiment.write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    train(experiment, run_dir=run, progress=False)
    saved = sorted((run / "checkpoints").glob("*_steps.zip"), key=lambda p: int(p.stem.split("_")[-2]))
    assert len(saved) >= 5, saved  # a short run has checkpoints to resume from
    (run / "model.zip").write_bytes((run / "model.zip").read_bytes()[:100])  # cut
    saved[-1].write_bytes(b"")  # cut to nothing
    result = train(None, resume=run, overrides={"timesteps": 64}, progress=False)
    assert result.timesteps > int(saved[-2].stem.split("_")[-2])
    assert json.loads((run / "run.json").read_text())["status"] == "done"
    for file in (run / "model.zip", *(run / "checkpoints").glob("*_steps.zip")):
        file.write_bytes(b"x")  # none loads now
    with pytest.raises(ConfigError, match=r"no saved model loads; tried, newest first: model\.zip"):
        train(None, resume=run, progress=False)


def test_a_file_saved_atomically_is_whole_or_untouched(tmp_path: Path) -> None:
    target = tmp_path / "model.zip"
    target.write_bytes(b"old")

    def fails(path: Path) -> None:
        path.write_bytes(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        save_atomically(fails, target)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]
    save_atomically(lambda path: path.write_bytes(b"new"), target)
    assert target.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]


def test_checkpoints_are_scaled_to_the_run_unless_set() -> None:
    assert TrainingSection(timesteps=20_000).checkpoint_steps == 2_000
    assert TrainingSection(timesteps=10_000_000).checkpoint_steps == 50_000
    assert TrainingSection(timesteps=5).checkpoint_steps == 1
    assert TrainingSection(timesteps=20_000, checkpoint_every=7_000).checkpoint_steps == 7_000
