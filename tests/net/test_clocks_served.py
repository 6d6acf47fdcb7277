"""A clocked FMI 3.0 FMU (clocks3) where a user puts it next: served by ``fmu-bridge node`` and
driven through :class:`RemoteFmuEnv`, and isolated in a child process (``--isolate``,
``model.isolation``). Each gives the in-process :class:`FmuEnv`'s observations bit for bit, with the
experiment's ``clock_intervals`` and ``clock_schedule`` honoured (tick counters in closed form).
Real ``fmu-bridge node`` processes on a loopback Zenoh router."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env import RemoteFmuEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from tests.conftest import Loopback, node_process

pytestmark = pytest.mark.integration

H = 0.06  # neither the clocks' intervals nor the schedule hits a sample time: counts are unambiguous
SAMPLES = 20
SCHEDULE = (0.5, 1.1)
FIXED = 0.2  # c_fixed's interval set by the experiment (the FMU's own is 0.25)
AGENT_TICKS = (3, 7)  # samples whose action ticks `trigger` (at the sample's start)
OUTPUTS = ["x", "u", "n_fixed", "n_trigger", "t_trigger", "n_const", "n_out", "n_countdown"]


def _experiment(tmp_path: Path, interface: str, **model: Any) -> Path:
    text = {
        "model": {
            "fmu": f"example:clocks3:3.0:{interface}",
            "interface": interface,
            "step_size": H,
            "episode_duration": H * SAMPLES,
            "clock_intervals": {"c_fixed": FIXED},
            "clock_schedule": {"trigger": list(SCHEDULE)},
            **model,
        },
        "actions": {"inputs": ["r", "trigger"], "low": {"r": -1.0}, "high": {"r": 1.0}},
        "observations": {"outputs": OUTPUTS},
        "reward": {"expression": "-abs(x - 0.5)"},
    }
    path = tmp_path / f"clocks3_{interface}.yaml"
    path.write_text(yaml.safe_dump(text))
    return path


def _episodes(env: Any) -> np.ndarray:
    """Two episodes (the second replays the clocks from the reset): observation rows."""
    rows = []
    for seed in (0, 1):
        rows.append(env.reset(seed=seed)[0])
        for j in range(SAMPLES):
            action = np.array([0.5 * math.sin(j), 1.0 if j in AGENT_TICKS else 0.0], dtype=np.float32)
            obs, _, terminated, truncated, _ = env.step(action)
            rows.append(obs)
            assert terminated is False and truncated == (j == SAMPLES - 1)
    return np.array(rows)


def _check_closed_form(rows: np.ndarray) -> None:
    """The clock settings reached the FMU: c_fixed ticks at 0.05 + 0.2 k (not the XML's 0.25), and
    trigger at the schedule's times and at the agent's ticks."""
    for episode in range(2):
        for j in range(SAMPLES + 1):
            t = j * H
            obs = rows[episode * (SAMPLES + 1) + j]
            n_fixed = math.floor((t - 0.05) / FIXED) + 1 if t >= 0.05 else 0
            n_trigger = sum(s <= t for s in SCHEDULE) + sum(k < j for k in AGENT_TICKS)
            assert obs[OUTPUTS.index("n_fixed")] == n_fixed, (episode, j)
            assert obs[OUTPUTS.index("n_trigger")] == n_trigger, (episode, j)


@pytest.fixture(scope="module")
def in_process(tmp_path_factory: pytest.TempPathFactory) -> dict[str, np.ndarray]:
    """The in-process env's two episodes, per interface (the reference)."""
    tmp = tmp_path_factory.mktemp("clocks_served")
    out = {}
    for interface in ("cs", "me", "se"):
        with FmuEnv(load_experiment(_experiment(tmp, interface))) as env:
            out[interface] = _episodes(env)
        _check_closed_form(out[interface])
    return out


@pytest.mark.parametrize("isolate", [False, True], ids=["in_node", "isolated_in_node"])
@pytest.mark.parametrize("interface", ["cs", "me", "se"])
def test_a_node_serves_a_clocked_fmu_as_the_in_process_env_runs_it(
    loopback: Loopback, tmp_path: Path, in_process: dict[str, np.ndarray], interface: str, isolate: bool
) -> None:
    path = _experiment(tmp_path, interface)
    with node_process(path, "clk", loopback, *(["--isolate"] if isolate else [])):
        remote = RemoteFmuEnv(path, "clk", session=loopback.session, prefix=loopback.prefix, timeout_s=30.0)
        try:
            rows = _episodes(remote)
        finally:
            remote.close()
    _check_closed_form(rows)
    np.testing.assert_array_equal(rows, in_process[interface])


@pytest.mark.parametrize("interface", ["cs", "me", "se"])
def test_an_isolated_clocked_plant_runs_as_in_process(
    tmp_path: Path, in_process: dict[str, np.ndarray], interface: str
) -> None:
    """``model.isolation`` from the file, and the plant built directly."""
    by_file = load_experiment(_experiment(tmp_path, interface, isolation={"timeout": 60}))
    with FmuEnv(by_file) as env:
        assert env.plant.isolated  # type: ignore[attr-defined]
        np.testing.assert_array_equal(_episodes(env), in_process[interface])
    experiment = load_experiment(_experiment(tmp_path, interface))
    with FmuEnv(experiment, plant=IsolatedFmuPlant(experiment_plant_spec(experiment), timeout_s=60.0)) as env:  # type: ignore[arg-type]
        np.testing.assert_array_equal(_episodes(env), in_process[interface])
