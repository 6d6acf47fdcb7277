"""Recordings of a system of FMUs: every component's outputs on its own topic, read back by
independent readers (mcap + mcap_ros2, rosbags), and one Rerun plot per component."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from bridge.env.fmu_env import FmuEnv
from bridge.recording import meta
from bridge.recording.env_recorder import RecordMcap

EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"
COMPONENTS = ("controller", "motor", "load")


@pytest.fixture(scope="module")
def recorded(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, list[dict[str, Any]], dict[str, list[str]]]:
    """Two episodes of the example system; per sample the env's info and the plant's own values."""
    path = tmp_path_factory.mktemp("system_recording") / "system.mcap"
    env = RecordMcap(FmuEnv(EXAMPLE), path, agent="sine")  # more than a block: packed in bulk too
    plant = env.unwrapped.plant  # type: ignore[attr-defined]
    samples: list[dict[str, Any]] = []
    for seed in (0, 1):
        _, info = env.reset(seed=seed)
        samples.append({**info, "components": plant.component_outputs()})
        for k in range(160):
            action = np.array([0.5 + 0.4 * np.sin(k / 7)], dtype=np.float32)
            *_, terminated, truncated, info = env.step(action)
            samples.append({**info, "components": plant.component_outputs()})
            if terminated or truncated:
                break
    names = meta.component_names(plant)
    output_names = list(env.unwrapped.output_names)  # type: ignore[attr-defined]
    env.close()
    for s in samples:
        s["named"] = dict(zip(output_names, s["outputs"].tolist()))
    return path, samples, names


def mcap_messages(path: Path) -> dict[str, list[tuple[int, Any]]]:
    found: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            found[channel.topic].append((message.log_time, decoded))
    return found


def test_each_component_has_its_outputs_on_its_own_topic(recorded: Any) -> None:
    path, samples, names = recorded
    messages = mcap_messages(path)
    assert set(names) == set(COMPONENTS)
    assert {"omega", "current"} <= set(names["motor"]) and "torque" in names["load"]
    for component in COMPONENTS:
        topic = meta.component_topic(component)
        got = messages[topic]
        assert len(got) == len(samples), topic
        for (_, message), sample in zip(got, samples):
            stamp_ns = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
            assert stamp_ns == round(sample["time_s"] * 1e9)
            assert list(message.name) == names[component]
            values = dict(zip(message.name, message.position))
            assert values == sample["components"][component]
            for name, value in values.items():  # what the env also observed: equal to its info
                if f"{component}.{name}" in sample["named"]:
                    assert value == sample["named"][f"{component}.{name}"]
    motor_omega = [dict(zip(m.name, m.position))["omega"] for _, m in messages["/components/motor/outputs"]]
    assert max(abs(v) for v in motor_omega) > 1.0  # the motor really turned
    assert messages[meta.OUTPUTS] and len(messages[meta.OUTPUTS]) == len(samples)  # unchanged topics


def test_rosbags_reads_the_component_topics(recorded: Any) -> None:
    path, samples, _ = recorded
    counts: dict[str, int] = defaultdict(int)
    last: dict[str, list[float]] = {}
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, _, raw in reader.messages():
            counts[connection.topic] += 1
            if connection.topic.startswith(meta.COMPONENTS):
                last[connection.topic] = reader.deserialize(raw, connection.msgtype).position.tolist()
    for component in COMPONENTS:
        topic = meta.component_topic(component)
        assert types[topic] == "sensor_msgs/msg/JointState"
        assert counts[topic] == len(samples)
        assert last[topic] == list(samples[-1]["components"][component].values())


def test_replay_groups_plots_by_component(recorded: Any, tmp_path: Path) -> None:
    rr_chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk is not installed")
    from bridge.recording.replay import replay

    path, _, names = recorded
    target = replay(path, save=tmp_path / "system.rrd")
    assert target is not None
    entities = set()
    for chunk in rr_chunk.RrdReader(target).stream().collect().stream():
        if not chunk.is_static:
            entities.add(chunk.entity_path)
    for component in COMPONENTS:
        for name in names[component]:
            assert f"/components/{component}/outputs/{name}" in entities
