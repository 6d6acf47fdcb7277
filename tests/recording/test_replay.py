"""Replay in Rerun (read back with Rerun's own chunk readers, rendered headless) and over Zenoh."""

from __future__ import annotations

import ctypes.util
import glob
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError, DependencyMissing
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.recording.env_recorder import RecordMcap
from bridge.recording.export import columns
from bridge.recording.reader import read_recording
from bridge.recording.writer import McapWriter
from tests.conftest import Loopback

rr_chunk = pytest.importorskip(
    "rerun.chunk", reason="rerun-sdk is not installed (pip install 'fmu-bridge[viz]')"
)
from bridge.recording import meta  # noqa: E402
from bridge.recording.replay import PALETTE, replay  # noqa: E402

CONTINUOUS = example_experiment("cartpole_continuous")
GAINS = (1.0, 1.5, 30.0, 5.0)
runner = CliRunner()
_load_plugins()
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three cart-pole episodes driven by a PD controller with a sine on top."""
    path = tmp_path_factory.mktemp("replay") / "cartpole.mcap"
    env = RecordMcap(FmuEnv(CONTINUOUS), path, agent="pd")
    for episode in range(3):
        _, info = env.reset(seed=episode)
        for k in range(150):
            force = max(-10.0, min(10.0, sum(g * v for g, v in zip(GAINS, info["outputs"]))))
            action = np.array([force / 10.0 + 0.3 * np.sin(k / 10)], dtype=np.float32)
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
    env.close()
    return path


def chunks(reader: Any) -> dict[str, list[Any]]:
    """Record batches of a Rerun chunk reader, by entity path (temporal data only)."""
    found: dict[str, list[Any]] = {}
    for chunk in reader.stream().collect().stream():
        if not chunk.is_static:
            found.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return found


def column(batches: list[Any], name: str) -> list[Any]:
    """Values of component ``name`` (clears, which break lines between episodes, have none)."""
    return [v for batch in batches if name in batch.schema.names for v in batch.column(name).to_pylist()]


def test_rrd_holds_every_signal_on_the_recording_timelines(recording: Path, tmp_path: Path) -> None:
    target = replay(recording, save=tmp_path / "run.rrd")
    assert target == tmp_path / "run.rrd"
    data = read_recording(recording)
    stored = chunks(rr_chunk.RrdReader(target))
    outputs = columns(data, data.series[meta.OUTPUTS])
    for name in ("x", "theta", "theta_dot"):
        batches = stored[f"/outputs/{name}"]
        times = [
            t
            for b in batches
            if "Scalars:scalars" in b.schema.names
            for t in b.column("time").cast("int64").to_pylist()
        ]
        rows = sorted(zip(times, column(batches, "Scalars:scalars")))
        assert [v[0] for _, v in rows] == outputs[name].tolist()
        assert [t for t, _ in rows] == outputs["log_time_ns"].tolist()
    reward = stored["/reward"]
    assert sorted(v[0] for v in column(reward, "Scalars:scalars")) == sorted(
        data.series[meta.REWARD].values.tolist()
    )
    names = {field for batches in stored.values() for b in batches for field in b.schema.names}
    assert {"time", "sim_time", "step", "episode_0", "episode_1", "episode_2"} <= names
    assert "/cartpole/cart" in stored and "/cartpole/pole" in stored
    assert len(column(stored["/events"], "TextLog:text")) == 6  # a start and an end per episode
    documents = [text for row in column(stored["/scenario"], "TextDocument:text") for text in row]
    by_episode = {text.split("\n", 1)[0]: text for text in documents}  # stored order is not episode order
    assert sorted(by_episode) == ["## Episode 0", "## Episode 1", "## Episode 2"]
    assert "seed: 1" in by_episode["## Episode 1"]


def test_one_episode_can_be_replayed_alone(recording: Path, tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["replay", str(recording), "--save", str(tmp_path / "e1.rrd"), "--episode", "1"]
    )
    assert result.exit_code == 0, result.output + repr(result.exception)
    stored = chunks(rr_chunk.RrdReader(tmp_path / "e1.rrd"))
    data = read_recording(recording)
    outputs = columns(data, data.series[meta.OUTPUTS])
    expected = outputs["x"][outputs["episode"] == 1]
    assert sorted(v[0] for v in column(stored["/outputs/x"], "Scalars:scalars")) == sorted(expected.tolist())
    with pytest.raises(BridgeError, match=r"--episode 7: .* has episodes \[0, 1, 2\]"):
        replay(recording, save=tmp_path / "e7.rrd", episode=7)


def test_rerun_reads_the_mcap_itself(recording: Path) -> None:
    """Rerun's own MCAP reader turns the JointState channels into plotted scalars with names."""
    stored = chunks(rr_chunk.McapReader(recording))
    data = read_recording(recording)
    for topic in (meta.OUTPUTS, meta.OBSERVATIONS, meta.ACTIONS):
        batches = stored[f"{topic}/position"]
        np.testing.assert_array_equal(np.array(column(batches, "Scalars:scalars")), data.series[topic].values)
        assert column(batches, "SeriesLines:names")[0] == data.series[topic].names


def test_replay_without_rerun_says_how_to_install_it(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(DependencyMissing, match=r'pip install "fmu-bridge\[viz\]"'):
        replay(recording, save=tmp_path / "x.rrd")


# -- headless screenshots ----------------------------------------------------------------------------
def _screenshot_tools() -> str:
    binary = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if binary is None:
        pytest.skip("the rerun viewer binary is not installed (pip install 'fmu-bridge[viz]')")
    icds = glob.glob("/usr/share/vulkan/icd.d/*.json") + glob.glob("/etc/vulkan/icd.d/*.json")
    if ctypes.util.find_library("vulkan") is None or not icds:
        pytest.skip(
            "headless Rerun needs Vulkan: install mesa-vulkan-drivers and libvulkan1 (.ci/apt-packages)"
        )
    return binary


def screenshot(binary: str, source: Path, png: Path) -> Any:
    from PIL import Image

    result = subprocess.run(
        [binary, "--headless", "--new", "--bind", "127.0.0.1", str(source),
         "--screenshot-to", str(png), "--window-size", "1280x800"],
        capture_output=True, text=True, timeout=180, check=False,
    )  # fmt: skip
    assert result.returncode == 0 and png.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    return np.asarray(Image.open(png).convert("RGB")).astype(np.int16)


def shot_until(binary: str, source: Path, png: Path, drawn: Any, attempts: int = 8) -> Any:
    """The one-shot CLI screenshot can fire before lazily loaded chunks are drawn (seen on a busy
    machine): take it again, a few times at most, until the data are in the picture."""
    for _ in range(attempts):
        image = screenshot(binary, source, png)
        if drawn(image):
            break
    return image


def palette_pixels(image: Any, tolerance: int = 40) -> dict[tuple[int, int, int], int]:
    return {c: int((np.abs(image - np.array(c)).max(axis=2) <= tolerance).sum()) for c in PALETTE}


def coloured_pixels(image: Any) -> int:
    return int(((image.max(axis=2) - image.min(axis=2)) > 80).sum())


@pytest.mark.integration
@pytest.mark.timeout(1800)  # up to 8 viewer launches on a busy machine
def test_headless_screenshots_show_plotted_data_not_a_blank_canvas(recording: Path, tmp_path: Path) -> None:
    import rerun as rr

    binary = _screenshot_tools()
    rrd = replay(recording, save=tmp_path / "run.rrd")
    assert rrd is not None
    empty_rrd = tmp_path / "empty.rrd"
    stream = rr.RecordingStream("fmu_bridge", recording_id="empty")
    stream.save(str(empty_rrd))
    stream.flush()
    stream.disconnect()
    blank = palette_pixels(screenshot(binary, empty_rrd, tmp_path / "empty.png"))

    def plotted(image: Any) -> list[tuple[int, int, int]]:
        ours = palette_pixels(image)
        return [c for c in PALETTE if ours[c] > blank[c] + 1000]  # series colours we set, drawn as lines

    shot = shot_until(binary, rrd, tmp_path / "run.png", lambda image: len(plotted(image)) >= 5)
    assert len(plotted(shot)) >= 5, (palette_pixels(shot), blank)
    # The MCAP itself, opened by the viewer, against an MCAP with the same channels and no messages.
    empty_mcap = tmp_path / "empty.mcap"
    writer = McapWriter(empty_mcap)
    meta.open_channels(writer, [meta.OUTPUTS, meta.EVENTS], {meta.OUTPUTS: ["x", "theta"]})
    writer.close()
    without = coloured_pixels(screenshot(binary, empty_mcap, tmp_path / "empty_mcap.png"))
    mcap_shot = shot_until(
        binary, recording, tmp_path / "mcap.png", lambda i: coloured_pixels(i) > without + 5000
    )
    assert coloured_pixels(mcap_shot) > without + 5000, (coloured_pixels(mcap_shot), without)


# -- playback over Zenoh -------------------------------------------------------------------------------
@pytest.mark.integration
def test_publish_plays_the_outputs_back_as_node_frames(recording: Path, loopback: Loopback) -> None:
    frames: list[proto.Frame] = []
    keys = proto.Keys(loopback.prefix, "rec")
    sub = loopback.session.declare_subscriber(
        keys.outputs, lambda s: frames.append(proto.decode(s.payload.to_bytes()))
    )  # type: ignore[attr-defined]
    try:
        result = subprocess.run(
            [sys.executable, "-m", "bridge.cli", "replay", str(recording), "--publish", "--node", "rec",
             "--rate", "0", "--connect", loopback.endpoint, "--prefix", loopback.prefix],
            capture_output=True, text=True, env=ENV, timeout=120, check=False,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        data = read_recording(recording)
        outputs = columns(data, data.series[meta.OUTPUTS])
        deadline = time.monotonic() + 30  # the last frames may still be on their way (a loaded machine)
        while len(frames) < len(outputs["x"]) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        sub.undeclare()
    assert [f.kind for f in frames] == [proto.OUTPUTS] * len(outputs["x"])
    assert [(f.episode, f.step) for f in frames] == list(
        zip(outputs["episode"].tolist(), outputs["step"].tolist())
    )
    assert [f.sim_time_ns for f in frames] == data.series[meta.OUTPUTS].stamp_ns.tolist()
    np.testing.assert_array_equal(np.array([f.values for f in frames]), data.series[meta.OUTPUTS].values)


@pytest.mark.integration
def test_publish_paces_by_the_recording_clock_and_answers_info(recording: Path, loopback: Loopback) -> None:
    from bridge.net.remote import describe_nodes
    from bridge.net.transport import ZenohOptions
    from bridge.recording.playback import publish

    data = read_recording(recording)
    first_episode = data.episodes[0]
    span_s = (first_episode.end_ns or 0) / 1e9  # episode 0 starts at 0 on the recording clock
    rate = span_s / 1.0  # the episode should take about one second
    stop, sent = threading.Event(), []
    worker = threading.Thread(
        target=lambda: sent.append(
            publish(recording, node="paced", options=ZenohOptions(connect=(loopback.endpoint,)),
                    prefix=loopback.prefix, rate=rate, episode=0, stop=stop, wait_s=0.0)
        )
    )  # fmt: skip
    started = time.monotonic()
    worker.start()
    try:
        deadline = time.monotonic() + 30  # the publisher's session and queryable (a loaded machine)
        info: dict[str, Any] = {}
        while time.monotonic() < deadline and "output_names" not in info:
            info = describe_nodes(loopback.session, ["paced"], prefix=loopback.prefix, timeout_s=0.5)[0]
        assert info["output_names"] == ["x", "x_dot", "theta", "theta_dot"] and info["mode"] == "replay"
    finally:
        worker.join(timeout=30)
        stop.set()
    elapsed = time.monotonic() - started
    assert sent == [first_episode.steps + 1]  # step 0 and every step of the episode
    assert 0.8 < elapsed < 60.0  # paced (about 1 s), and it ends
