"""Replay fixes: per-episode timelines on every stream, INFO starts, separate action labels, no line
across episodes, tracking references, and a clear failure without a display."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from bridge.recording.env_recorder import RecordMcap

rr_chunk = pytest.importorskip(
    "rerun.chunk", reason="rerun-sdk is not installed (pip install 'fmu-bridge[viz]')"
)
from bridge.recording.replay import replay  # noqa: E402


@pytest.fixture(scope="module")
def motor_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two DC-motor episodes (scenario step_up: omega_ref steps to 100 rad/s at 0.2 s), constant 12 V."""
    path = tmp_path_factory.mktemp("motor") / "motor.mcap"
    env = RecordMcap(FmuEnv(example_experiment("dcmotor_tracking")), path, agent="pid")
    for seed in range(2):
        env.reset(seed=seed, options={"scenario": "step_up"})
        for _ in range(60):
            env.step(np.array([0.5], dtype=np.float32))
    env.close()
    return path


def batches(rrd: Path) -> dict[str, list[Any]]:
    found: dict[str, list[Any]] = {}
    for chunk in rr_chunk.RrdReader(rrd).stream().collect().stream():
        found.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return found


def values(found: list[Any], name: str) -> list[Any]:
    return [v for b in found if name in b.schema.names for v in b.column(name).to_pylist()]


def test_every_stream_is_on_the_episode_timelines(motor_recording: Path, tmp_path: Path) -> None:
    stored = batches(replay(motor_recording, save=tmp_path / "m.rrd") or tmp_path)
    for entity in ("/reward", "/scenario", "/events", "/outputs/omega", "/tracking/omega/reference"):
        names = {n for b in stored[entity] for n in b.schema.names}
        assert {"episode_0", "episode_1"} <= names, (entity, names)
    reward_times = [t for b in stored["/reward"] if "episode_1" in b.schema.names
                    for t in b.column("episode_1").cast("int64").to_pylist() if t is not None]  # fmt: skip
    assert min(reward_times) == 10_000_000 and len(reward_times) == 60  # t_1 = one 10 ms sample in


def test_starts_are_info_and_actions_have_their_own_labels(motor_recording: Path, tmp_path: Path) -> None:
    stored = batches(replay(motor_recording, save=tmp_path / "m.rrd") or tmp_path)
    texts = values(stored["/events"], "TextLog:text")
    levels = values(stored["/events"], "TextLog:level")
    flat = [(str(t), str(lvl)) for t, lvl in zip(texts, levels)]
    starts = [lvl for text, lvl in flat if "starts" in text]
    assert len(starts) == 2 and all("INFO" in lvl for lvl in starts), flat
    force = values(stored["/actions/voltage"], "SeriesLines:names")
    agent = values(stored["/agent_action/voltage"], "SeriesLines:names")
    assert force[0] == ["voltage [V]"] and agent[0] == ["voltage (agent action, -1..1)"]


def test_no_line_joins_two_episodes_and_the_reference_is_the_scenario(
    motor_recording: Path, tmp_path: Path
) -> None:
    stored = batches(replay(motor_recording, save=tmp_path / "m.rrd") or tmp_path)
    clears = values(stored["/outputs/omega"], "Clear:is_recursive")
    assert len(clears) == 2  # one after each episode
    reference = [v[0] for v in values(stored["/tracking/omega/reference"], "Scalars:scalars")]
    assert sorted(set(reference)) == [0.0, 100.0] and reference.count(0.0) == 2 * 20  # step at 0.2 s


def test_replay_without_a_display_fails_and_suggests_save(motor_recording: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "replay", str(motor_recording)],
        capture_output=True, text=True, env=env, timeout=120, check=False,
    )  # fmt: skip
    assert result.returncode != 0
    assert "neither DISPLAY nor WAYLAND_DISPLAY" in result.stderr + result.stdout
    assert "--save" in result.stderr + result.stdout
    assert "opened" not in result.stdout


@pytest.mark.integration  # starts the Rerun viewer (bridge.recording.replay) as a process
def test_a_viewer_that_dies_at_start_is_an_error(
    motor_recording: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bridge.errors import BridgeError

    monkeypatch.setenv("DISPLAY", ":97")  # no X server there: the viewer exits at once, after it
    # logged where it listened (loopback only), or it drops the connection once it fails
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    died = r"(?s)Rerun viewer (exited at start|closed the connection).*--save"  # its stderr tail varies
    with pytest.raises(BridgeError, match=died):
        replay(motor_recording)
