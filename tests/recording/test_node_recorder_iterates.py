"""``record --node`` on a node whose steps are repeated (a system's fixed-point iteration).

Frames go through ``NodeRecorder.handle`` (a real in-process node on loopback answers the
recorder's info query) and the file is read back by mcap + mcap_ros2: one message per step and
topic remains, holding the last pass; a stream without repeats keeps every frame, in arrival
order, at the stamps the protocol gives.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.recording import meta
from bridge.recording.node_recorder import NodeRecorder
from bridge.serving import experiment_node
from tests.conftest import Loopback

pytestmark = pytest.mark.integration
CLIENT = 7


@dataclass
class Node:
    """What the recorder learns from the node: sizes and timing."""

    outputs: int
    inputs: int
    start_ns: int
    sampling_ns: int


Factory = Callable[[Path], tuple[NodeRecorder, Node]]


@pytest.fixture
def recorder(loopback: Loopback) -> Iterator[Factory]:
    """Recorders of one real node (cart-pole, in this process) on a loopback router."""

    node = experiment_node(
        example_experiment("cartpole_continuous"),
        name="iterated",
        prefix=loopback.prefix,
        session=loopback.session,
    )

    def make(path: Path) -> tuple[NodeRecorder, Node]:
        made = NodeRecorder(loopback.session, "iterated", path, prefix=loopback.prefix, timeout_s=30)
        d = made.description
        start, sampling = round(d["start_time_s"] * 1e9), round(d["sampling_time_s"] * 1e9)
        return made, Node(len(d["output_names"]), len(d["input_names"]), start, sampling)

    try:
        yield make
    finally:
        node.close()


def action(node: Node, episode: int, step: int, value: float, flags: int = 0) -> tuple[str, bytes]:
    frame = proto.encode_values(proto.ACTION, episode, step, CLIENT, [value] * node.inputs, flags=flags)
    return "actions", frame


def outputs(node: Node, episode: int, step: int, value: float) -> tuple[str, bytes]:
    time_ns = node.start_ns + step * node.sampling_ns
    return "outputs", proto.encode_values(proto.OUTPUTS, episode, step, time_ns, [value] * node.outputs)


def iterated_step(node: Node, episode: int, step: int, passes: int) -> list[tuple[str, bytes]]:
    """One macro step as a node's wire carries it: the first pass saves, the others restore."""
    frames = []
    for n in range(passes):
        flags = proto.SAVE_STATE if n == 0 else proto.RESTORE_STATE
        frames += [
            action(node, episode, step, 100 * step + n, flags),
            outputs(node, episode, step, 10 * step + n),
        ]
    return frames


def read(path: Path) -> list[tuple[str, int, Any]]:
    """Every message in file order: topic, log time, decoded message (independent reader)."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [
            (channel.topic, message.log_time, decoded)
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False)
        ]


def stamp(message: Any) -> int:
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def test_only_the_last_pass_of_each_step_is_recorded(recorder: Factory, tmp_path: Path) -> None:
    rec, node = recorder(tmp_path / "iterated.mcap")
    passes = {1: 1, 2: 3, 3: 2, 4: 4}
    frames = [f for step, n in passes.items() for f in iterated_step(node, 1, step, n)]
    wrong_size = proto.encode_values(proto.OUTPUTS, 1, 4, 0, [99.0] * (node.outputs + 1))
    frames.insert(-1, ("outputs", wrong_size))  # a malformed frame between passes replaces nothing
    frames += iterated_step(node, 2, 1, 2) + iterated_step(node, 2, 2, 3)
    frames.append(("outputs", proto.encode_message(proto.REJECT, 2, 3, 0, "state: no state saved")))
    for topic, payload in frames:
        rec.handle(topic, payload)
    rec.close()
    assert rec.stats.repeated == 2 * ((0 + 2 + 1 + 3) + (1 + 2))  # passes after the first, per topic
    assert rec.stats.malformed == 1 and rec.stats.unplaced == 0 and rec.stats.episodes == 2

    messages = read(rec.writer.path)
    recorded = [(t, round(m.position[0]), stamp(m)) for t, _, m in messages if t != meta.EVENTS]
    expected = []
    for episode_passes in (passes, {1: 2, 2: 3}):
        for step, n in episode_passes.items():
            expected.append((meta.ACTIONS, 100 * step + n - 1, node.start_ns + (step - 1) * node.sampling_ns))
            expected.append((meta.OUTPUTS, 10 * step + n - 1, node.start_ns + step * node.sampling_ns))
    assert recorded == expected  # one per step and topic, the last pass, in the order they came
    events = [json.loads(m.data) for t, _, m in messages if t == meta.EVENTS]
    assert [e["event"] for e in events] == [
        "episode_start",
        "episode_end",
        "episode_start",
        "reject",
        "episode_end",
    ]
    assert events[1]["steps"] == 4 and events[4]["steps"] == 2
    kinds = [t for t, _, _ in messages]
    assert kinds[-3:] == [meta.OUTPUTS, meta.EVENTS, meta.EVENTS]  # the reject after the steps before it
    log_times = [log for t, log, _ in messages if t == meta.OUTPUTS]
    assert log_times == sorted(set(log_times))  # no two outputs at one time


def test_a_stream_without_repeats_keeps_every_frame_in_arrival_order(
    recorder: Factory, tmp_path: Path
) -> None:
    rec, node = recorder(tmp_path / "plain.mcap")
    frames = []
    for step in range(1, 7):
        frames += [action(node, 1, step, 100 + step), outputs(node, 1, step, 10 + step)]
    frames[5], frames[6] = frames[6], frames[5]  # outputs of step 3 after the action of step 4
    frames += [action(node, 3, 1, 201), outputs(node, 3, 1, 21)]
    frames.append(("outputs", proto.encode_message(proto.ERROR, 3, 2, 0, "fmi2DoStep failed")))
    for topic, payload in frames:
        rec.handle(topic, payload)
    rec.close()
    assert rec.stats.repeated == 0 and rec.stats.frames == {"actions": 7, "outputs": 8}

    messages = [(t, log, m) for t, log, m in read(rec.writer.path) if t != meta.EVENTS]
    offsets = {1: 0, 3: 7 * node.sampling_ns}  # episode 3 starts one sampling period after t_6
    expected = []
    for topic, payload in frames[:-1]:
        frame = proto.decode(payload)
        step_ns = node.start_ns + (frame.step - (1 if frame.kind == proto.ACTION else 0)) * node.sampling_ns
        log = step_ns - node.start_ns + offsets[frame.episode]
        expected.append(("/" + topic, log, step_ns, float(frame.values[0])))
    got = [(t, log, stamp(m), float(m.position[0])) for t, log, m in messages]
    assert got == expected
    events = [json.loads(m.data) for t, _, m in read(rec.writer.path) if t == meta.EVENTS]
    assert [e["event"] for e in events] == [
        "episode_start",
        "episode_end",
        "episode_start",
        "fmu_error",
        "episode_end",
    ]
