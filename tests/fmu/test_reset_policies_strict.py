"""Every reset policy against ``strict_reset``, an FMU whose reset misbehaves as real exporters' do.

``strict_reset`` (bridge/models/strict.py) asks to terminate at ``t_end = 1 s``: ten steps of
0.1 s. Its ``fmi2Reset`` keeps the terminated flag of a finished run (``quirks`` bit 1) and its
state functions refuse an instance reset since instantiation (bit 2). ``restore`` of the first
initialisation and ``reinstantiate`` give ten-step episodes on it; ``reset`` cannot; ``auto`` must
never snapshot (or reuse) a state it has not seen work, so it gives ten-step episodes too, with one
value set or several, and the same trajectory as ``reinstantiate`` bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import parse_experiment
from bridge.fmu import Model
from bridge.models.strict import KEEPS_TERMINATED, STATE_REFUSED_AFTER_RESET, strict_reset_fmu

STEPS = 10  # t_end / h
BOTH = KEEPS_TERMINATED | STATE_REFUSED_AFTER_RESET
ONE_SET: list[dict[str, Any]] = [{}] * 4
ALTERNATING = [{"k": 1.0}, {"k": 2.0}, {"k": 1.0}, {"k": 2.0}, {"k": 0.5}, {"k": 1.0}]


@pytest.fixture(scope="module")
def fmu() -> Path:
    return strict_reset_fmu()


def episodes(fmu: Path, policy: str, value_sets: list[dict[str, Any]], quirks: int) -> list[list[float]]:
    """The output ``x`` after every step of one episode per value set, run until the FMU terminates."""
    runs = []
    with Model(fmu, reset_policy=policy) as model:  # type: ignore[arg-type]
        for i, values in enumerate(value_sets):
            start = model.initialize if i == 0 else model.reset
            start({"quirks": quirks, "u": 0.5, **values})
            xs: list[float] = []
            while not model.terminated and len(xs) <= 2 * STEPS:
                model.advance(1)
                xs.append(model.get(["x"])["x"])
            runs.append(xs)
    return runs


@pytest.mark.parametrize("quirks", [KEEPS_TERMINATED, BOTH])
@pytest.mark.parametrize("policy", ["auto", "restore", "reinstantiate"])
def test_every_episode_runs_to_the_end_on_an_fmu_whose_reset_keeps_its_terminated_flag(
    fmu: Path, policy: str, quirks: int
) -> None:
    runs = episodes(fmu, policy, ONE_SET, quirks)
    assert [len(xs) for xs in runs] == [STEPS] * len(ONE_SET)
    assert all(xs == runs[0] for xs in runs)


@pytest.mark.parametrize("quirks", [KEEPS_TERMINATED, BOTH])
def test_auto_over_changing_value_sets_equals_reinstantiate_bit_for_bit(fmu: Path, quirks: int) -> None:
    auto = episodes(fmu, "auto", ALTERNATING, quirks)
    assert [len(xs) for xs in auto] == [STEPS] * len(ALTERNATING)
    assert auto == episodes(fmu, "reinstantiate", ALTERNATING, quirks)
    assert auto[0] != auto[1], "the value sets give different trajectories"


def test_the_strict_fmu_really_keeps_its_terminated_flag_through_fmi_reset(fmu: Path) -> None:
    """What ``auto`` works around: the ``reset`` policy trusts the FMU and gets one-step episodes."""
    runs = episodes(fmu, "reset", ONE_SET, KEEPS_TERMINATED)
    assert [len(xs) for xs in runs] == [STEPS, 1, 1, 1]
    assert [len(xs) for xs in episodes(fmu, "reset", ONE_SET, 0)] == [STEPS] * len(ONE_SET)


def test_the_env_with_auto_reset_gives_full_length_episodes(fmu: Path, tmp_path: Path) -> None:
    data = {
        "model": {"fmu": str(fmu), "step_size": 0.1, "sampling_time": 0.1, "episode_duration": 5.0},
        "actions": {"inputs": ["u"], "low": {"u": 0.0}, "high": {"u": 1.0}},
        "observations": {"outputs": ["x"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    exp = parse_experiment(data, source=tmp_path / "strict_reset.yaml")
    assert exp.model.reset_policy == "auto"
    lengths = []
    with FmuEnv(exp) as env:
        for seed in range(4):
            env.reset(seed=seed)
            steps, done = 0, False
            while not done:
                _, _, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
                steps, done = steps + 1, terminated or truncated
            lengths.append(steps)
    assert lengths == [STEPS] * 4


def test_the_reset_policy_says_why_its_episodes_end_at_once(
    fmu: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """``reset`` keeps the user's choice, but an evaluation's wrong mean no longer comes without a word."""
    with caplog.at_level("WARNING", logger="bridge.fmu.model"):
        runs = episodes(fmu, "reset", ONE_SET, KEEPS_TERMINATED)
    assert [len(xs) for xs in runs] == [STEPS, 1, 1, 1]
    said = [r.getMessage() for r in caplog.records if "terminated run" in r.getMessage()]
    assert len(said) == 1, "said once"
    assert "set reset_policy to auto, restore or reinstantiate" in said[0]
