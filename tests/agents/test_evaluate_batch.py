"""evaluate --batch gives the metrics of the one-episode-at-a-time path, value for value."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from agents.evaluate import evaluate
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment


@pytest.mark.parametrize("chunk", [1024, 2], ids=["one-batch", "chunks-of-2"])
def test_batch_evaluation_equals_the_episode_by_episode_evaluation(
    chunk: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # chunks of 2 over 5 episodes: the batch's FMU instances serve chunk after chunk (2, 2, then 1)
    monkeypatch.setattr("agents.evaluate_batch.CHUNK", chunk)
    path = Path(example_experiment("dcmotor_tracking"))
    batch = evaluate(["pid", "random"], path, episodes=5, batch=True)
    single = evaluate(["pid", "random"], path, episodes=5)
    assert len(batch.rows) == len(single.rows) == 2 * 2 * 5  # agents x evaluation scenarios x episodes
    for b, s in zip(batch.rows, single.rows):
        assert b.keys() == s.keys()
        for key, value in s.items():
            both_nan = isinstance(value, float) and math.isnan(value) and math.isnan(b[key])
            assert both_nan or b[key] == value, (key, b[key], value)


def test_batch_evaluation_refuses_to_record() -> None:
    with pytest.raises(ConfigError, match="--no-record"):
        evaluate(["zero"], Path(example_experiment("dcmotor_tracking")), batch=True, record_dir=Path("x"))
