"""The one-call native sample against the Python path: same trajectories, errors and ends.

Each case runs the same seeded episodes twice, once with the native sample and once with
``FMU_BRIDGE_NO_NATIVE=1`` (three ctypes calls a sample from Python), and compares everything
the env returns bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError, StepError
from bridge.experiment.examples import example_experiment

TYPED = (
    "model: {{fmu: '{fmu}', step_size: 0.1, sampling_time: 0.2, episode_duration: 3.0}}\n"
    "actions: {{inputs: [real_in], low: {{real_in: -2}}, high: {{real_in: 2}}}}\n"
    "observations: {{outputs: [real_out, real_integral, real_scaled]}}\n"
    "reward: {{terms: [{{alive: 1.0}}]}}\n"
    "scenarios: {{breaks: {{parameters: {{fail_at_step: 5}}}}, "
    "stops: {{parameters: {{terminate_at_time: 1.0}}}}, fine: {{}}}}\n"
    "schedule: {{mode: fixed}}\n"
)


def _env(experiment: Any, native: bool, monkeypatch: pytest.MonkeyPatch) -> FmuEnv:
    with monkeypatch.context() as patch:
        if native:
            patch.delenv("FMU_BRIDGE_NO_NATIVE", raising=False)
        else:
            patch.setenv("FMU_BRIDGE_NO_NATIVE", "1")
        env = FmuEnv(experiment)
        env.reset(seed=0)
    assert env.plant.native_stepping is native  # type: ignore[attr-defined]
    return env


def _run(env: FmuEnv, scenario: str | None, episodes: int = 2) -> list[Any]:
    trace: list[Any] = []
    actions = np.random.default_rng(7)
    for episode in range(episodes):
        options = {"scenario": scenario} if scenario else None
        obs, info = env.reset(seed=episode, options=options)
        trace.append((obs.tolist(), info["outputs"].tolist(), info["time_s"]))
        done = False
        while not done:
            action = env.action_space.sample() if env.action_space.shape == () else None
            if action is None:
                action = actions.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            try:
                obs, reward, terminated, truncated, info = env.step(action)
            except StepError as exc:
                trace.append(("error", str(exc), exc.step, exc.episode, exc.time_s))
                with pytest.raises(BridgeError, match="call reset"):
                    env.step(action)
                break
            trace.append(
                (obs.tolist(), reward, terminated, truncated, info["outputs"].tolist(), info["time_s"])
            )
            done = terminated or truncated
        trace.append(("end", info.get("reason")))
    return trace


@pytest.mark.parametrize("name", ["cartpole_balance", "cartpole_continuous", "vehicle_path"])
def test_examples_step_identically_on_both_paths(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    traces = []
    for native in (True, False):
        env = _env(example_experiment(name), native, monkeypatch)
        env.action_space.seed(3)
        traces.append(_run(env, None))
        env.close()
    assert traces[0] == traces[1]
    assert len(traces[0]) > 20


@pytest.mark.parametrize("version", ["2.0", "3.0"])
@pytest.mark.parametrize("scenario", ["fine", "breaks", "stops"])
def test_errors_and_termination_are_the_same_on_both_paths(
    version: str, scenario: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bridge.models import example_fmu

    path = tmp_path / "typed.yaml"
    path.write_text(TYPED.format(fmu=example_fmu("typed", version, "cs")))
    traces = []
    for native in (True, False):
        env = _env(path, native, monkeypatch)
        traces.append(_run(env, scenario))
        env.close()
    assert traces[0] == traces[1]
    ends = [t for t in traces[0] if t[0] in ("error", "end")]
    if scenario == "breaks":
        assert ends[0][0] == "error" and "fail_at_step reached" in ends[0][1], ends
        # doStep call 5 is in sample 3 (2 FMU steps a sample); episode 1 was the warm-up reset
        assert "the model failed at step 3 of episode 2" in ends[0][1]
    elif scenario == "stops":
        assert ends[-1] == ("end", "fmu"), ends  # termination.on_fmu_terminate defaults to true
    else:
        assert ends[-1] == ("end", "time"), ends
