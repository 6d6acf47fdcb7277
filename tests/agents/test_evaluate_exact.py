"""``evaluate``'s fixed agents apply the user's physical values exactly, in float64: ``constant:V``
reaches the FMU as V (the feedthrough FMU's output ``y`` is its input ``u`` as the FMU received it),
``zero`` leaves a tunable parameter at its start value, a clipped value warns once naming the value,
the bound and the variable, and a model without actions takes only ``zero``. In process, with
worker processes and in a batch env."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from agents.evaluate import evaluate
from bridge.errors import ConfigError
from bridge.models import example_fmu
from bridge.recording.env_recorder import slug

VALUES = (0.9, 0.1, 2.3, 1.2345678901234567, 0.30000000000000004)  # none of them a float32


def _experiment(tmp_path: Path, model: str, actions: str, outputs: str) -> Path:
    path = tmp_path / f"{model}.yaml"
    path.write_text(
        f"model: {{fmu: '{example_fmu(model, '2.0', 'cs')}', step_size: 0.01, sampling_time: 0.01, "
        "episode_duration: 0.05}\n"
        f"actions: {actions}\n"
        f"observations: {{outputs: {outputs}}}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return path


FEEDTHROUGH = "{inputs: [u], low: {u: 0.1}, high: {u: 2.3}}"


def _positions(recording: Path) -> dict[str, list[list[float]]]:
    with AnyReader([recording]) as reader:
        return {
            c.topic: [
                [float(v) for v in reader.deserialize(raw, c.msgtype).position]
                for _, _, raw in reader.messages([c])
            ]
            for c in reader.connections
            if c.topic in ("/actions", "/outputs")
        }


@pytest.mark.parametrize(
    "how", ["in_process", "recorded", pytest.param("workers", marks=pytest.mark.integration), "batch"]
)
def test_constants_reach_the_fmu_exactly(tmp_path: Path, how: str) -> None:
    path = _experiment(tmp_path, "feedthrough", FEEDTHROUGH, "[y]")
    agents = [f"constant:{v!r}" for v in VALUES]
    result = evaluate(
        agents,
        path,
        episodes=2,
        workers=2 if how == "workers" else 1,
        batch=how == "batch",
        record_dir=tmp_path / "recordings" if how == "recorded" else None,
    )
    for agent, value in zip(agents, VALUES):
        (traces,) = [t for (name, _), t in result.traces.items() if name == agent]
        assert len(traces) == 2
        for trace in traces:
            assert trace.inputs["u"].tolist() == [value] * len(trace.inputs["u"])
            # y after each step is u as the FMU received it, compared with ==
            assert trace.signals["y"][1:].tolist() == [value] * (len(trace.time_s) - 1), (agent, value)
            assert float(np.float32(value)) != value  # a float32 action could not have carried it
    if how == "recorded":  # the recordings, read by an independent reader (rosbags), say the same
        for recording in result.recordings:
            value = next(v for a, v in zip(agents, VALUES) if recording.name.startswith(f"{slug(a)}__"))
            rows = _positions(recording)
            assert rows["/actions"] == [[value]] * 10  # 2 episodes of 5 steps
            stepped = [row for row in rows["/outputs"] if row != [0.0]]  # not the resets' y = 0
            assert stepped == [[value]] * 10
        assert len(result.recordings) == len(agents)


def test_a_clipped_constant_warns_once_and_zero_keeps_a_parameter_at_its_start(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = _experiment(tmp_path, "feedthrough", FEEDTHROUGH, "[y]")
    with caplog.at_level(logging.WARNING):
        result = evaluate(["constant:2.5"], path, episodes=3)
    (traces,) = result.traces.values()
    assert all(t.signals["y"][1:].tolist() == [2.3] * (len(t.time_s) - 1) for t in traces)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        "agent 'constant:2.5': 2.5 on u is outside its bounds [0.1, 2.3]: its maximum 2.3 is applied instead"
    ]
    tuned = _experiment(tmp_path, "pi_controller", "{inputs: [kp], low: {kp: 0.5}, high: {kp: 3.0}}", "[u]")
    (traces,) = evaluate(["zero"], tuned, episodes=1).traces.values()
    assert traces[0].inputs["kp"].tolist() == [1.0] * len(traces[0].inputs["kp"])  # kp's start, not 0.5


def test_a_model_without_actions_takes_only_zero(tmp_path: Path) -> None:
    path = _experiment(tmp_path, "feedthrough", "{inputs: []}", "[y]")
    assert evaluate(["zero"], path, episodes=1).rows
    for agent in ("constant:1.0", "random"):
        with pytest.raises(ConfigError, match=rf"agent '{agent}': the experiment has no actions"):
            evaluate([agent], path, episodes=1)
