"""A recording or a state file that cannot be written (a full disk) fails with a clear error and
leaves no temporary file; the disk is made "full" for real with the process's file size limit
(RLIMIT_FSIZE: the kernel refuses writes past it with EFBIG, as it refuses them with ENOSPC)."""

from __future__ import annotations

import contextlib
import resource
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError, StateFileError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.fmu import state_file
from bridge.plant.state_run import save_state
from bridge.recording.env_recorder import record_env

MOTOR = example_experiment("dcmotor_tracking")


@contextlib.contextmanager
def file_size_limit(size: int) -> Iterator[None]:
    """Writes past ``size`` bytes of any file fail (EFBIG) while the block runs."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # an error, not a signal
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)


def test_a_full_disk_during_env_step_is_a_bridge_error_naming_the_recording(tmp_path: Path) -> None:
    """It once came out of ``env.step`` as a bare OSError: short episodes end in small chunks that
    the file buffers, and the flush at an episode's end is where the disk says it is full."""
    with FmuEnv(MOTOR) as env:
        recorder = record_env(env, tmp_path, run_name="full")
        recorder.reset(seed=0)
        part = next(tmp_path.glob("full.mcap*"))
        caught: BaseException | None = None
        with file_size_limit(part.stat().st_size + 64):
            try:
                for _ in range(1_000):
                    for _ in range(3):
                        recorder.step(env.action_space.sample())
                    recorder.reset()  # the episode ends: its chunk is written and flushed
            except BaseException as exc:  # what env.step raised, whatever it is
                caught = exc
        with contextlib.suppress(BridgeError):
            recorder.close()
    assert isinstance(caught, BridgeError), repr(caught)
    message = str(caught)
    assert "writing the recording failed: File too large" in message and str(part) in message


def test_a_state_save_that_cannot_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    spec = {
        "name": "saver",
        "model": {"fmu": "example:slow_init:2.0:cs", "step_size": 0.05, "episode_duration": 1.0,
                  "parameters": {"warmup_steps": 0}},
        "actions": {"inputs": ["power"], "low": {"power": -50.0}, "high": {"power": 50.0}},
        "observations": {"outputs": ["T"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }  # fmt: skip
    (tmp_path / "saver.yaml").write_text(yaml.safe_dump(spec))
    saved = save_state(load_experiment(tmp_path / "saver.yaml"), tmp_path / "first.state", until_s=0.1)
    data = state_file.read(saved.path)
    out = tmp_path / "out"
    out.mkdir()
    with file_size_limit(64), pytest.raises(StateFileError) as caught:
        state_file.write(out / "s.state", data)
    assert list(out.iterdir()) == []  # no .tmp file left
    assert "cannot write the state file: File too large; free some space" in str(caught.value)
