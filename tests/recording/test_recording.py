"""MCAP recordings read back by independent readers (mcap + mcap_ros2, rosbags), crash safety,
the node recorder over real Zenoh, and the recording commands."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import textwrap
import time
import zlib
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk, MessageIndex
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as RosbagsReader
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError, DependencyMissing
from bridge.experiment.examples import example_experiment
from bridge.fmu import sha256
from bridge.net.ros2 import cdr
from bridge.recording.env_recorder import RecordMcap, record_env
from bridge.recording.export import columns, export_csv, export_parquet
from bridge.recording.reader import read_recording, recover
from bridge.recording.writer import FixedMessage, McapWriter, StepBlock
from tests.conftest import Loopback, node_process, wait_for_recorded, wait_for_recorder

CONTINUOUS = example_experiment("cartpole_continuous")
DISCRETE = example_experiment("cartpole_balance")
GAINS = (1.0, 1.5, 30.0, 5.0)
runner = CliRunner()
_load_plugins()
ENV = {**os.environ, "COLUMNS": "200", "PYTHONUNBUFFERED": "1"}


# -- helpers ---------------------------------------------------------------------------------------
def rosbags_messages(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message as (log time, decoded object), by topic, through rosbags' AnyReader."""
    found: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with AnyReader([path]) as reader:
        for connection, log_ns, raw in reader.messages():
            found[connection.topic].append((log_ns, reader.deserialize(raw, connection.msgtype)))
    return found


def mcap_ros2_messages(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """The same through mcap's reader with the mcap_ros2 dynamic decoder (schemas from the file)."""
    found: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            found[channel.topic].append((message.log_time, decoded))
    return found


def push(outputs: Any) -> float:
    return max(-10.0, min(10.0, sum(g * float(v) for g, v in zip(GAINS, outputs))))


def run_episodes(env: Any, episodes: int, steps: int, discrete: bool) -> dict[str, list[Any]]:
    """Drive ``env`` and keep everything it returned (what the recording must hold)."""
    seen: dict[str, list[Any]] = defaultdict(list)
    for e in range(episodes):
        obs, info = env.reset(seed=100 + e)
        seen["obs"].append(np.asarray(obs, dtype=np.float64))
        seen["outputs"].append(np.asarray(info["outputs"]))
        seen["obs_t"].append(info["time_s"])
        for k in range(steps):
            force = push(info["outputs"]) + 2.0 * np.sin(k / 7)
            action: Any = int(force > 0) if discrete else np.array([force / 10.0], dtype=np.float32)
            obs, reward, terminated, truncated, info = env.step(action)
            seen["inputs"].append(list(env.task.applied_inputs))
            seen["agent"].append(np.atleast_1d(np.asarray(action, dtype=np.float64)))
            seen["obs"].append(np.asarray(obs, dtype=np.float64))
            seen["outputs"].append(np.asarray(info["outputs"]))
            seen["obs_t"].append(info["time_s"])
            seen["reward"].append(float(reward))
            if terminated or truncated:
                break
        seen["episode_steps"].append(k + 1)
    return seen


def values(messages: list[tuple[int, Any]], field: str = "position") -> np.ndarray:
    return np.array([np.asarray(getattr(m, field), dtype=np.float64) for _, m in messages])


def stamps_ns(messages: list[tuple[int, Any]]) -> list[int]:
    return [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for _, m in messages]


# -- the writer --------------------------------------------------------------------------------------
def test_writer_files_are_valid_for_mcap_and_rosbags_with_indexes_and_crcs(tmp_path: Path) -> None:
    path = tmp_path / "w.mcap"
    rng = np.random.default_rng(0)
    writer = McapWriter(path, chunk_size=4096)
    schema = writer.add_schema(cdr.JOINT_STATE, "ros2msg", cdr.schema_text(cdr.JOINT_STATE).encode())
    f64 = writer.add_schema(cdr.FLOAT64, "ros2msg", cdr.schema_text(cdr.FLOAT64).encode())
    a, b, r = (writer.add_channel(t, s) for t, s in (("/a", schema), ("/b", schema), ("/r", f64)))
    la, lb = cdr.JointStateLayout.of(["u"]), cdr.JointStateLayout.of(["p", "q", "rr"])
    block = StepBlock([FixedMessage(a, 0, la), FixedMessage(b, 1, lb), FixedMessage(r, 1, None)])
    writer.add_metadata("run", {"seed": "5", "text": "é"})
    written: dict[int, list[tuple[int, bytes]]] = defaultdict(list)
    t = 0
    for _ in range(40):  # blocks and single messages interleaved, over many chunks
        n = int(rng.integers(1, 30))
        t0 = t + np.arange(n, dtype=np.int64) * 10
        t1 = t0 + 10
        vals = [rng.normal(size=(n, 1)), rng.normal(size=(n, 3)), rng.normal(size=n)]
        writer.add_block(*block.pack([(t0, t0), (t1, t1)], vals))
        for k in range(n):
            written[a].append((int(t0[k]), la.pack(int(t0[k]), vals[0][k].tolist())))
            written[b].append((int(t1[k]), lb.pack(int(t1[k]), vals[1][k].tolist())))
            written[r].append((int(t1[k]), cdr.encode_float64(float(vals[2][k]))))
        t = int(t1[-1])
        writer.add_message(b, t, lb.pack(t, [1.0, 2.0, 3.0]))
        written[b].append((t, lb.pack(t, [1.0, 2.0, 3.0])))
    writer.add_attachment("notes.txt", "text/plain", b"hello", log_time=7)
    writer.close()
    assert path.is_file() and not (tmp_path / "w.mcap.part").exists()

    with path.open("rb") as stream:
        reader = make_reader(stream)
        stats = reader.get_summary().statistics
        assert stats.message_count == sum(len(v) for v in written.values())
        assert stats.channel_message_counts == {ch: len(v) for ch, v in written.items()}
        assert stats.chunk_count > 10 and stats.message_start_time == 0 and stats.message_end_time == t
        read: dict[int, list[tuple[int, bytes]]] = defaultdict(list)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            read[channel.id].append((message.log_time, message.data))
        assert read == written
        assert [(m.name, m.metadata) for m in reader.iter_metadata()] == [("run", {"seed": "5", "text": "é"})]
        assert [(x.name, x.data, x.log_time) for x in reader.iter_attachments()] == [
            ("notes.txt", b"hello", 7)
        ]
    with path.open("rb") as stream:  # chunk and data-section CRCs
        assert sum(1 for _ in StreamReader(stream, validate_crcs=True).records) > stats.message_count
    _check_message_indexes(path)
    _check_summary_crc(path)
    with RosbagsReader(path) as bag:
        assert bag.message_count == stats.message_count
        assert {c.topic: c.msgcount for c in bag.connections} == {
            "/a": len(written[a]),
            "/b": len(written[b]),
            "/r": len(written[r]),
        }


def _check_message_indexes(path: Path) -> None:
    """Every message index entry points at a message of its channel with its log time."""
    import zstandard

    chunk_data, checked = b"", 0
    with path.open("rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                chunk_data = zstandard.ZstdDecompressor().decompress(
                    record.data, max_output_size=record.uncompressed_size
                )
            elif isinstance(record, MessageIndex):
                for log_time, offset in record.records:
                    opcode, _length, channel, _seq, log = struct.unpack_from("<BQHIQ", chunk_data, offset)
                    assert (opcode, channel, log) == (0x05, record.channel_id, log_time)
                    checked += 1
    assert checked > 100


def _check_summary_crc(path: Path) -> None:
    data = path.read_bytes()
    footer = len(data) - 8 - 29  # footer record: 1 + 8 + 20 bytes
    summary_start, offsets_start, crc = struct.unpack_from("<QQI", data, footer + 9)
    assert offsets_start > summary_start > 0
    assert zlib.crc32(data[summary_start : footer + 9 + 16]) == crc


# -- RecordMcap ----------------------------------------------------------------------------------------
def test_recorded_env_reads_back_exactly_in_rosbags_and_mcap_ros2(tmp_path: Path) -> None:
    path = tmp_path / "eval.mcap"
    env = RecordMcap(FmuEnv(CONTINUOUS), path, agent="pd-controller", seed=100)
    seen = run_episodes(env, episodes=3, steps=120, discrete=False)
    env.close()
    for messages in (rosbags_messages(path), mcap_ros2_messages(path)):
        np.testing.assert_array_equal(values(messages["/observations"]), np.array(seen["obs"]))
        np.testing.assert_array_equal(values(messages["/outputs"]), np.array(seen["outputs"]))
        np.testing.assert_array_equal(values(messages["/actions"]), np.array(seen["inputs"]))
        np.testing.assert_array_equal(values(messages["/agent_action"]), np.array(seen["agent"]))
        assert [m.data for _, m in messages["/reward"]] == seen["reward"]
        assert stamps_ns(messages["/outputs"]) == [round(t * 1e9) for t in seen["obs_t"]]
        assert messages["/outputs"][0][1].name == ["x", "x_dot", "theta", "theta_dot"]
        assert messages["/actions"][0][1].name == ["force"]
    # the recording clock: episodes back to back, never overlapping; actions at t_k, results at t_k+1
    outputs, actions = rosbags_messages(path)["/outputs"], rosbags_messages(path)["/actions"]
    logs = [t for t, _ in outputs]
    assert logs == sorted(logs) and len(set(logs)) == len(logs)
    starts = np.cumsum([0, *[n + 1 for n in seen["episode_steps"][:-1]]])
    assert [logs[s] for s in starts] == [0, *[logs[s - 1] + 20_000_000 for s in starts[1:]]]
    assert stamps_ns(actions)[:2] == [0, 20_000_000] and actions[0][0] == 0


def test_events_metadata_and_attachment_describe_the_run(tmp_path: Path) -> None:
    path = tmp_path / "eval.mcap"
    fmu_env = FmuEnv(CONTINUOUS)
    env = RecordMcap(fmu_env, path, agent="pd-controller", seed=100)
    seen = run_episodes(env, episodes=2, steps=600, discrete=False)
    env.close()
    events = [json.loads(m.data) for _, m in rosbags_messages(path)["/events"]]
    assert [e["event"] for e in events] == ["episode_start", "episode_end"] * 2
    start, end = events[0], events[1]
    assert start["seed"] == 100 and start["scenario"] == "nominal"
    assert set(start["drawn"]) == {"theta0", "theta_dot0", "m_pole", "length"}
    assert end["steps"] == seen["episode_steps"][0] and end["reason"] in ("time", "bounds:x", "bounds:theta")
    assert end["return"] == sum(seen["reward"][: seen["episode_steps"][0]])
    drawn = rosbags_messages(path)["/scenario"][0][1]
    assert dict(zip(drawn.name, drawn.position.tolist())) == start["drawn"]
    with path.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "ros2"
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        schemas = {s.name: s for s in reader.get_summary().schemas.values()}
        attachments = list(reader.iter_attachments())
    assert schemas[cdr.JOINT_STATE].encoding == "ros2msg"
    assert schemas[cdr.JOINT_STATE].data.decode() == cdr.schema_text(cdr.JOINT_STATE)
    run = meta["fmu_bridge"]
    assert (
        run["fmu_sha256"] == sha256(fmu_env.plant.fmu_path)
        and run["agent"] == "pd-controller"
        and run["seed"] == "100"
    )
    assert yaml.safe_load(run["config"]) == fmu_env.experiment.model_dump(mode="json")
    assert meta["versions"]["fmu-bridge"] == "0.1.0" and "numpy" in meta["versions"]
    assert json.loads(meta["run_summary"]["returns"]) == [
        e["return"] for e in events if e["event"] == "episode_end"
    ]
    assert [(a.name, a.data) for a in attachments] == [(CONTINUOUS.name, CONTINUOUS.read_bytes())]


def test_discrete_actions_record_the_index_and_the_force(tmp_path: Path) -> None:
    env = record_env(FmuEnv(DISCRETE), directory=tmp_path / "rec", run_name="ppo__mixed", agent="x.zip")
    seen = run_episodes(env, episodes=1, steps=50, discrete=True)
    env.close()
    assert env.path == tmp_path / "rec" / "ppo__mixed.mcap" and env.path.is_file()
    again = record_env(FmuEnv(DISCRETE), directory=tmp_path / "rec", run_name="ppo__mixed")
    again.close()
    assert again.path.name == "ppo__mixed-1.mcap"  # never overwrites
    messages = rosbags_messages(env.path)
    assert messages["/agent_action"][0][1].name == ["index"]
    np.testing.assert_array_equal(values(messages["/agent_action"])[:, 0], np.array(seen["agent"])[:, 0])
    np.testing.assert_array_equal(
        values(messages["/actions"])[:, 0], np.where(np.array(seen["agent"])[:, 0] > 0, 10.0, -10.0)
    )


def test_an_existing_or_unfinished_recording_is_never_overwritten(tmp_path: Path) -> None:
    (tmp_path / "run.mcap.part").write_bytes(b"left by a killed run")
    with pytest.raises(BridgeError, match="fmu-bridge recover"):
        RecordMcap(FmuEnv(DISCRETE), tmp_path / "run.mcap")
    assert (tmp_path / "run.mcap.part").read_bytes() == b"left by a killed run"
    RecordMcap(FmuEnv(DISCRETE), tmp_path / "done.mcap").close()
    with pytest.raises(BridgeError, match="--force"):
        RecordMcap(FmuEnv(DISCRETE), tmp_path / "done.mcap")
    RecordMcap(FmuEnv(DISCRETE), tmp_path / "done.mcap", overwrite=True).close()


# -- crash safety ---------------------------------------------------------------------------------------
CHILD = textwrap.dedent(
    """
    import json, signal, sys
    import numpy as np
    # a user's program gets Ctrl-C; started from a background job it would inherit SIGINT ignored
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from bridge.env.fmu_env import FmuEnv
    from bridge.recording.env_recorder import RecordMcap
    env = RecordMcap(FmuEnv(sys.argv[1]), sys.argv[2], chunk_size=16384)
    episode = 0
    while True:
        obs, info = env.reset(seed=episode)
        rows = [info["outputs"].tolist()]
        done = False
        while not done:
            obs, r, terminated, truncated, info = env.step(np.array([0.1], dtype=np.float32))
            rows.append(info["outputs"].tolist())
            done = terminated or truncated
        print(json.dumps({"episode": episode, "outputs": rows}), flush=True)
        episode += 1
    """
)


def _start_child(tmp_path: Path, target: Path) -> tuple[subprocess.Popen[str], list[dict[str, Any]]]:
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    child = subprocess.Popen(
        [sys.executable, str(script), str(CONTINUOUS), str(target)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    assert child.stdout is not None
    episodes = []
    for _ in range(5):
        line = child.stdout.readline()
        assert line, child.stderr.read() if child.stderr else ""
        episodes.append(json.loads(line))
    return child, episodes


@pytest.mark.integration
def test_a_killed_recorder_leaves_a_part_file_readable_up_to_its_last_chunk(tmp_path: Path) -> None:
    target = tmp_path / "killed.mcap"
    child, episodes = _start_child(tmp_path, target)
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=30)
    part = tmp_path / "killed.mcap.part"
    assert part.is_file() and not target.exists()
    with pytest.raises(BridgeError, match="unfinished recording exists"):
        read_recording(target)
    ours = read_recording(part)  # our reader, directly on the .part
    assert not ours.complete
    outputs = columns(ours, ours.series["/outputs"])
    for episode in episodes[:3]:  # flushed at their ends, long before the kill
        rows = outputs["episode"] == episode["episode"]
        got = np.column_stack([outputs[n][rows] for n in ("x", "x_dot", "theta", "theta_dot")])
        np.testing.assert_array_equal(got, np.array(episode["outputs"]))
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "recover", str(part)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    with RosbagsReader(target) as bag:  # an independent reader on the recovered file
        counts = {c.topic: c.msgcount for c in bag.connections}
    assert counts == ours.message_counts
    recovered = rosbags_messages(target)["/outputs"]
    np.testing.assert_array_equal(values(recovered), ours.series["/outputs"].values)


@pytest.mark.integration
def test_ctrl_c_finishes_the_file(tmp_path: Path) -> None:
    target = tmp_path / "interrupted.mcap"
    child, episodes = _start_child(tmp_path, target)
    child.send_signal(signal.SIGINT)  # KeyboardInterrupt: nothing in the script catches it
    child.wait(timeout=60)
    assert target.is_file() and not (tmp_path / "interrupted.mcap.part").exists()
    with RosbagsReader(target) as bag:
        assert bag.message_count > 0
    data = read_recording(target)
    assert data.complete and len(data.episodes) >= len(episodes)
    assert all(e.end_ns is not None for e in data.episodes)  # every episode ends, the cut one as closed
    assert [e.reason == "closed" for e in data.episodes].count(True) <= 1
    assert all(e.reason != "closed" for e in data.episodes[:-1])


# -- the node recorder over real Zenoh ------------------------------------------------------------------
@pytest.mark.integration
def test_record_node_gives_the_outputs_a_remote_env_received(loopback: Loopback, tmp_path: Path) -> None:
    """Two recordings of one remote run: the node's topics (``record --node``, a subprocess) and
    the RemoteFmuEnv itself wrapped in RecordMcap; both hold exactly what the env received."""
    from bridge.env import RemoteFmuEnv

    target, env_file = tmp_path / "node.mcap", tmp_path / "env.mcap"
    with node_process(CONTINUOUS, "cp", loopback):
        recorder = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli", "record", "--node", "cp", "-o", str(target),
             "--connect", loopback.endpoint, "--prefix", loopback.prefix],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
        )  # fmt: skip
        try:
            wait_for_recorder(loopback, "cp")
            remote = RemoteFmuEnv(CONTINUOUS, "cp", session=loopback.session, prefix=loopback.prefix)
            env = RecordMcap(remote, env_file, agent="sine")
            received, sent, first, every = [], [], [], []
            for seed in (1, 2):
                _, info = env.reset(seed=seed)
                first.append(info["outputs"].copy())
                every.append((0, info["outputs"].copy()))  # the node publishes step 0 after a reset
                for k in range(40):
                    _, _, terminated, truncated, info = env.step(np.array([np.sin(k / 5)], dtype=np.float32))
                    received.append((info["step"], info["outputs"].copy()))
                    every.append(received[-1])
                    sent.append(list(env.task.applied_inputs))
                    if terminated or truncated:
                        break
            description = remote.plant.client.description
            env.close()
            wait_for_recorded(loopback, "cp", {"outputs": len(every), "actions": len(sent)})
        finally:
            recorder.send_signal(signal.SIGINT)
            try:
                out, err = recorder.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                recorder.kill()  # never leave a recorder behind
                raise
    assert recorder.returncode == 0, err
    assert "wrote" in out and target.is_file()
    messages = rosbags_messages(target)
    np.testing.assert_array_equal(values(messages["/outputs"]), np.array([v for _, v in every]))
    np.testing.assert_array_equal(values(messages["/actions"]), np.array(sent))
    data = read_recording(target)
    table = columns(data, data.series["/outputs"])
    assert table["step"].tolist() == [s for s, _ in every]
    assert [e.index for e in data.episodes] == [1, 2]  # the env's episode numbers
    assert data.metadata["fmu_bridge"]["node"] == "cp"
    # The env's own recording has step 0 of each episode too (the reset reply).
    recorded = read_recording(env_file)
    table = columns(recorded, recorded.series["/outputs"])
    at_reset = table["step"] == 0
    np.testing.assert_array_equal(recorded.series["/outputs"].values[at_reset], np.array(first))
    np.testing.assert_array_equal(
        recorded.series["/outputs"].values[~at_reset], np.array([v for _, v in received])
    )
    run = recorded.metadata["fmu_bridge"]
    assert (
        run["env"] == "RemoteFmuEnv"
        and run["node"] == "cp"
        and run["fmu_sha256"] == description["fmu_sha256"]
    )


def test_observation_names_follow_the_history_layout() -> None:
    from types import SimpleNamespace

    from bridge.recording.meta import observation_names

    task = SimpleNamespace(observer=SimpleNamespace(names=["x", "theta"]))
    assert observation_names(task, 2) == ["x", "theta"]
    assert observation_names(task, 6) == ["x[t-2]", "theta[t-2]", "x[t-1]", "theta[t-1]", "x", "theta"]
    assert observation_names(task, 3) == ["obs[0]", "obs[1]", "obs[2]"]  # a wrapper changed the size


@pytest.mark.integration
def test_record_stops_after_duration_and_names_a_missing_node(loopback: Loopback, tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        ["record", "--node", "nobody", "-o", str(tmp_path / "x.mcap"), "--connect", loopback.endpoint,
         "--prefix", loopback.prefix, "--timeout", "1"],
    )  # fmt: skip
    assert result.exit_code != 0 and "no FMU node named 'nobody'" in str(result.exception)
    with node_process(CONTINUOUS, "rt", loopback, "--mode", "realtime", "--rate", "0"):
        started = time.monotonic()
        result = runner.invoke(
            app,
            ["record", "--node", "rt", "-o", str(tmp_path / "rt.mcap"), "--connect", loopback.endpoint,
             "--prefix", loopback.prefix, "--duration", "1.5", "--topics", "outputs"],
        )  # fmt: skip
        assert result.exit_code == 0, result.output + repr(result.exception)
        assert time.monotonic() - started < 20
    data = read_recording(tmp_path / "rt.mcap")
    outputs = data.series["/outputs"]
    assert len(outputs) > 10 and "/actions" not in data.series
    steps = np.diff(outputs.stamp_ns)
    assert np.all(steps > 0) and np.median(steps) == 20_000_000  # a real-time node publishes every sample


# -- commands ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, list[Any]]]:
    path = tmp_path_factory.mktemp("rec") / "small.mcap"
    env = RecordMcap(FmuEnv(CONTINUOUS), path, agent="pd")
    seen = run_episodes(env, episodes=2, steps=30, discrete=False)
    env.close()
    return path, seen


def test_info_lists_channels_episodes_and_metadata(
    small_recording: tuple[Path, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    from bridge.cli.options import console

    path, seen = small_recording
    # wide enough that no cell wraps, whatever the length of the temporary folder's path (the
    # console read COLUMNS when it was made, so setting it now would change nothing)
    monkeypatch.setattr(console, "width", 200)
    result = runner.invoke(app, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert "/observations" in result.output and "sensor_msgs/msg/JointState" in result.output
    assert "2 episode(s)" in result.output and "fmu_sha256" in result.output
    summary = json.loads(runner.invoke(app, ["info", str(path), "--json"]).output)
    counts = {c["topic"]: c["messages"] for c in summary["channels"]}
    assert counts["/reward"] == len(seen["reward"]) and counts["/outputs"] == len(seen["outputs"])
    assert summary["complete"] and [e["steps"] for e in summary["episodes"]] == seen["episode_steps"]


def test_export_writes_csv_and_parquet_with_the_recorded_values(
    small_recording: tuple[Path, Any], tmp_path: Path
) -> None:
    import pyarrow.parquet as pq

    path, seen = small_recording
    result = runner.invoke(
        app, ["export", str(path), "--csv", str(tmp_path / "csv"), "--parquet", str(tmp_path / "pq")]
    )
    assert result.exit_code == 0, result.output
    with (tmp_path / "csv" / "outputs.csv").open() as handle:
        header = handle.readline().strip().split(",")
        rows = np.array([[float(v) for v in line.split(",")] for line in handle])
    assert header == [
        "log_time_ns",
        "time_s",
        "episode",
        "step",
        "sim_time_s",
        "x",
        "x_dot",
        "theta",
        "theta_dot",
    ]
    np.testing.assert_array_equal(rows[:, 5:], np.array(seen["outputs"]))
    assert rows[:, 3].tolist() == [*range(seen["episode_steps"][0] + 1), *range(seen["episode_steps"][1] + 1)]
    table = pq.read_table(tmp_path / "pq" / "reward.parquet").to_pydict()
    assert table["reward"] == seen["reward"] and set(table) >= {"log_time_ns", "episode", "step"}
    assert runner.invoke(app, ["export", str(path)]).exit_code != 0  # no target given


def test_parquet_without_pyarrow_says_how_to_install_it(
    small_recording: tuple[Path, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(DependencyMissing, match="pip install pyarrow"):
        export_parquet(read_recording(small_recording[0]), tmp_path)
    assert export_csv(read_recording(small_recording[0]), tmp_path)  # CSV needs nothing extra


def test_recover_refuses_to_overwrite_and_to_write_over_its_input(
    small_recording: tuple[Path, Any], tmp_path: Path
) -> None:
    copy = tmp_path / "copy.mcap.part"
    copy.write_bytes(small_recording[0].read_bytes())
    out = recover(copy)
    assert out == tmp_path / "copy.mcap" and read_recording(out).complete
    with pytest.raises(BridgeError, match="--force"):
        recover(copy)
    with pytest.raises(BridgeError, match="other than the input"):
        recover(copy, copy)
    result = runner.invoke(app, ["recover", str(copy), "--force"])
    assert result.exit_code == 0 and "messages" in result.output


def test_recover_leaves_out_payloads_the_readers_skip(tmp_path: Path) -> None:
    """A message whose payload is not valid CDR for its type (a flipped bit where no CRC checks
    it) is skipped by the reader; recover leaves it out too, so what it writes reads clean."""
    from bridge.recording import meta
    from bridge.recording.reader import recover_file

    path = tmp_path / "damaged.mcap"
    layout = cdr.JointStateLayout.of(["x", "v"])
    with McapWriter(path) as writer:
        channels = meta.open_channels(writer, [meta.OUTPUTS], {meta.OUTPUTS: ["x", "v"]})
        writer.add_message(channels[meta.OUTPUTS], 0, layout.pack(0, [1.0, 2.0]))
        writer.add_message(channels[meta.OUTPUTS], 1, b"\x00\x01\x00\x00\xff\xff\xff\x7f")
        writer.add_message(channels[meta.OUTPUTS], 2, layout.pack(2, [3.0, 4.0]))
    damaged = read_recording(path)
    assert damaged.problem_count == 1 and "not valid" in damaged.problems[0]
    result = recover_file(path, tmp_path / "recovered.mcap")
    assert result.messages == 2
    assert any("left out 1 message(s) of /outputs that are not valid" in p for p in result.problems)
    again = read_recording(result.path)
    assert again.complete and not again.problem_count, again.problems
    np.testing.assert_array_equal(again.series[meta.OUTPUTS].values, [[1.0, 2.0], [3.0, 4.0]])
