"""A replay of the vehicle showcase, rendered by the Rerun viewer headless and read back.

The viewer runs with ``--headless --screenshot-to`` on Mesa's software Vulkan (lavapipe), so the
pictures are real pixels; ``.rrd`` contents are read back with Rerun's own chunk reader. The
tests check that a control engineer sees the reference and the output in one plot, and that
choosing an ``episode_N`` timeline shows that episode's reward, scenario and log.
"""

from __future__ import annotations

import ctypes.util
import glob
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.evaluate import baseline_settings
from agents.policies import make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.recording.env_recorder import RecordMcap

rr_chunk = pytest.importorskip(
    "rerun.chunk", reason="rerun-sdk is not installed (pip install 'fmu-bridge[viz]')"
)
from bridge.recording import replay_signals as sig  # noqa: E402
from bridge.recording.replay import replay as replay_to_rrd  # noqa: E402
from bridge.recording.replay import series_colour  # noqa: E402

AGENT = "policy"  # the recording's agent name: its colour is pink, far from the UI's greys
TRACKED = "/tracking/lateral_error"


@pytest.fixture(scope="module")
def vehicle_rrd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two episodes of the held-out ``mountain`` road driven by the experiment's PID baseline."""
    folder = tmp_path_factory.mktemp("vehicle_replay")
    experiment = load_experiment(example_experiment("vehicle_path"))
    policy = make_policy("pid", baseline_settings(experiment), name=AGENT)
    env = RecordMcap(FmuEnv(experiment), folder / "vehicle.mcap", agent=AGENT)
    task = env.unwrapped.task
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed, options={"scenario": "mountain"})
        policy.reset(task, seed)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy.act(obs, task.signal_dict()))
            done = terminated or truncated
    env.close()
    rrd = replay_to_rrd(folder / "vehicle.mcap", save=folder / "vehicle.rrd")
    assert rrd is not None
    return rrd


def stored(rrd: Path) -> dict[str, list[Any]]:
    """Record batches of every temporal chunk, by entity path."""
    found: dict[str, list[Any]] = {}
    for chunk in rr_chunk.RrdReader(rrd).stream().collect().stream():
        if not chunk.is_static:
            found.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return found


def on_timeline(batches: list[Any], timeline: str, component: str) -> list[Any]:
    """Values of ``component`` in the rows that have a time on ``timeline``."""
    out = []
    for batch in batches:
        if timeline not in batch.schema.names or component not in batch.schema.names:
            continue
        times = batch.column(timeline).to_pylist()
        out += [v for t, v in zip(times, batch.column(component).to_pylist()) if t is not None]
    return out


def test_reference_and_output_share_one_plot_and_episode_timelines_hold_every_panel(
    vehicle_rrd: Path,
) -> None:
    found = stored(vehicle_rrd)
    output = on_timeline(found[f"{TRACKED}/output"], "episode_1", "Scalars:scalars")
    reference = on_timeline(found[f"{TRACKED}/reference"], "episode_1", "Scalars:scalars")
    assert len(output) == len(reference) == 401  # after reset and each of 400 samples (20 s at 20 Hz)
    assert {v[0] for v in reference} == {0.0}  # lateral_ref: the path itself
    assert max(abs(v[0]) for v in output) > 0.01  # the car's real lateral error, not a copy
    reward = on_timeline(found["/reward"], "episode_1", "Scalars:scalars")
    assert len(reward) == 400
    documents = on_timeline(found["/scenario"], "episode_1", "TextDocument:text")
    assert len(documents) == 1 and "Episode 1" in str(documents[0]) and "mountain" in str(documents[0])
    log = [str(t) for t in on_timeline(found["/events"], "episode_1", "TextLog:text")]
    assert len(log) == 2 and "episode 1 starts" in log[0] and "episode 1 ends" in log[1], log


# -- pixels -------------------------------------------------------------------------------------------
def viewer() -> str:
    binary = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if binary is None:
        pytest.skip("the rerun viewer binary is not installed (pip install 'fmu-bridge[viz]')")
    icds = glob.glob("/usr/share/vulkan/icd.d/*.json") + glob.glob("/etc/vulkan/icd.d/*.json")
    if ctypes.util.find_library("vulkan") is None or not icds:
        pytest.skip("headless Rerun needs Vulkan: install mesa-vulkan-drivers and libvulkan1")
    return binary


def episode_layout(folder: Path, timeline: str) -> Path:
    """The replay's tracking plot, reward plot, scenario document and episode log in four quarters,
    on ``timeline``: a blueprint file the viewer applies to the recording (application fmu_bridge)."""
    import rerun.blueprint as rrb

    blueprint = rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(rrb.TimeSeriesView(origin=TRACKED), rrb.TimeSeriesView(origin="/reward")),
            rrb.Horizontal(rrb.TextDocumentView(origin="/scenario"), rrb.TextLogView(origin="/events")),
        ),
        rrb.TimePanel(state="collapsed", timeline=timeline, play_state="paused"),
        collapse_panels=True,
    )
    path = folder / f"{timeline}.rbl"
    blueprint.save("fmu_bridge", path)
    return path


def screenshot(binary: str, files: list[Path], png: Path) -> Any:
    from PIL import Image

    result = subprocess.run(
        [binary, "--headless", "--new", "--bind", "127.0.0.1", *map(str, files),
         "--screenshot-to", str(png), "--window-size", "1280x800"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert result.returncode == 0 and png.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    return np.asarray(Image.open(png).convert("RGB")).astype(np.int16)


def quarter(image: Any, row: int, col: int) -> Any:
    """One panel of the 2 x 2 layout, without the menu bar, panel titles and time panel."""
    height, width = image.shape[:2]
    top, bottom = (0.09, 0.47) if row == 0 else (0.56, 0.93)
    return image[int(top * height) : int(bottom * height), col * width // 2 : (col + 1) * width // 2]


def near(image: Any, rgb: tuple[int, int, int], tolerance: int = 30) -> Any:
    return np.abs(image - np.array(rgb)).max(axis=2) <= tolerance


def bright(image: Any) -> int:
    return int((image.min(axis=2) > 150).sum())


def horizontal_line_span(mask: Any) -> float:
    """The longest share of a row covered by ``mask`` (a horizontal line spans the plot)."""
    return float(mask.sum(axis=1).max() / mask.shape[1])


@pytest.mark.integration
@pytest.mark.timeout(1800)  # up to 8 viewer launches on a busy machine
def test_screenshot_of_an_episode_timeline_shows_reference_output_reward_and_text(
    vehicle_rrd: Path, tmp_path: Path
) -> None:
    import rerun as rr

    binary = viewer()
    layout = episode_layout(tmp_path, "episode_1")
    empty = tmp_path / "empty.rrd"
    stream = rr.RecordingStream("fmu_bridge", recording_id="empty")
    stream.save(str(empty))
    stream.disconnect()
    blank = screenshot(binary, [empty, layout], tmp_path / "blank.png")
    shot = screenshot(binary, [vehicle_rrd, layout], tmp_path / "episode_1.png")
    for _ in range(7):  # a busy machine can take the picture before the chunks are drawn
        if near(quarter(shot, 0, 0), sig.agent_colour(AGENT)).sum() > 2000:
            break
        shot = screenshot(binary, [vehicle_rrd, layout], tmp_path / "episode_1.png")
    tracking, reward = quarter(shot, 0, 0), quarter(shot, 0, 1)
    assert near(tracking, sig.agent_colour(AGENT)).sum() > 2000  # the output, in the agent's colour
    assert near(quarter(blank, 0, 0), sig.agent_colour(AGENT)).sum() < 100
    # the reference (0 m) is a near-white line across the same plot
    assert horizontal_line_span(near(tracking, sig.VIEWER_REFERENCE_RGB, 25)) > 0.6
    assert horizontal_line_span(near(quarter(blank, 0, 0), sig.VIEWER_REFERENCE_RGB, 25)) < 0.3
    assert near(reward, series_colour("/reward", 0)).sum() > 2000  # reward drawn on episode_1
    # scenario document and episode log: text where the empty recording has none
    assert bright(quarter(shot, 1, 0)) > bright(quarter(blank, 1, 0)) + 3000
    assert bright(quarter(shot, 1, 1)) > bright(quarter(blank, 1, 1)) + 3000
