"""A system of two slow plants (``models/slow_plant``), one of them a component served by a node
(``fmu-bridge system serve``): at the default deadlines it gives the in-process system's trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from tests.conftest import Loopback
from tests.plant.test_system_nodes import serve, trajectory

pytestmark = pytest.mark.integration  # a serve process, a Zenoh router on 127.0.0.1

SYSTEM = """\
name: slow-system
system:
  algorithm: {algorithm}
  components:
    first:
      fmu: example:slow_plant:2.0:cs
      parameters: {{step_delay_s: 0.2, init_delay_s: 1.0, tau: 0.5, x0: 0.3}}{node}
    second:
      fmu: example:slow_plant:2.0:cs
      parameters: {{step_delay_s: 0.2, init_delay_s: 1.0, tau: 0.5, x0: -0.2}}
  connections:
    - first.x -> second.u
model: {{step_size: 0.1, sampling_time: 0.1, episode_duration: 0.4}}
actions: {{inputs: [first.u], low: {{first.u: -1}}, high: {{first.u: 1}}}}
observations: {{outputs: [first.x, second.x]}}
reward: {{terms: [{{signal: {{name: second.x, norm: squared, weight: -1.0}}}}]}}
"""


def system(folder: Path, name: str, node: str | None) -> Path:
    path = folder / f"{name}.yaml"
    text = "\n      node: " + node if node else ""
    path.write_text(SYSTEM.format(algorithm="gauss_seidel", node=text))
    return path


def remote_env(file: Path, net: Loopback) -> FmuEnv:
    """The system with its node components, at NodeComponents' default deadline."""
    plant = SystemPlant(load_experiment(file), remote=NodeComponents(session=net.session, prefix=net.prefix))
    return FmuEnv(file, plant=plant)


def test_a_slow_component_in_a_node_gives_the_in_process_trajectory(
    loopback: Loopback, tmp_path: Path
) -> None:
    here, there = system(tmp_path, "here", None), system(tmp_path, "there", "slow-first")
    with serve(there, loopback, "first"), FmuEnv(here) as local, remote_env(there, loopback) as distributed:
        expected, got = trajectory(local, 0, steps=3), trajectory(distributed, 0, steps=3)
    np.testing.assert_array_equal(got, expected)
    assert len(expected) > 2 * 3, "the episode ran its samples"
