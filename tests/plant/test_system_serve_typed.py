"""Components with String, Binary and FMI 3.0 array outputs served by ``system serve`` (real
Zenoh on 127.0.0.1, a real serve process): the system runs as in process, none of those outputs
bound into the numeric groups, the array's elements served one by one."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.experiment.config import load_experiment
from bridge.net.system_node import NodeComponents
from bridge.plant.system.description import from_experiment
from bridge.plant.system.plant import SystemPlant
from bridge.serving.system import component_signals
from tests.conftest import Loopback
from tests.plant.test_system_nodes import serve

pytestmark = pytest.mark.integration
OBSERVED = ["t3.y[1,2]", "t3.y[1,1]", "t3.y[2,1]", "t.real_out"]


def typed_system(directory: Path, name: str, nodes: dict[str, str]) -> Path:
    """typed (a String output) drives element 2 of typed3's array input (typed3: a Binary output
    and a 2-D array output); the task drives typed's real_in and observes array elements."""
    components: dict[str, Any] = {"t": {"fmu": "example:typed:2.0"}, "t3": {"fmu": "example:typed3:3.0"}}
    for component, node in nodes.items():
        components[component]["node"] = node
    data = {
        "name": name,
        "model": {"step_size": 0.1, "episode_duration": 2.0},
        "system": {"components": components, "connections": ["t.real_out -> t3.u[2]"]},
        "actions": {"inputs": ["t.real_in"], "low": {"t.real_in": -5.0}, "high": {"t.real_in": 5.0}},
        "observations": {"outputs": OBSERVED},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run(plant: SystemPlant) -> tuple[np.ndarray, dict[str, dict[str, float]]]:
    with plant:
        plant.bind(["t.real_in"], OBSERVED)
        rows = [plant.reset({}, [0.5])]
        rows += [plant.step([0.5 + 0.25 * k]) for k in range(8)]
        recorded = plant.component_outputs()
    return np.array(rows), recorded


def test_string_binary_and_array_outputs_are_served(net: Loopback, tmp_path: Path) -> None:
    served = typed_system(tmp_path, "typed_served", {"t": "typed-node", "t3": "typed3-node"})
    exp = load_experiment(served)
    system = from_experiment(exp)
    _, t_outs = component_signals(exp, system, "t")
    _, t3_outs = component_signals(exp, system, "t3")
    assert "string_out" not in t_outs and "real_out" in t_outs
    assert "data_out" not in t3_outs and {"y[1,1]", "y[1,2]", "y[2,1]"} <= set(t3_outs)
    local, local_recorded = run(SystemPlant(load_experiment(typed_system(tmp_path, "typed_here", {}))))
    with serve(served, net):
        remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)
        distributed, recorded = run(SystemPlant(load_experiment(served), remote=remote))
    np.testing.assert_array_equal(distributed, local)
    assert recorded == local_recorded
    assert distributed[-1][0] == 0.5 + 0.25 * 6  # real_in -> real_out -> u[2] -> y[1,2], a step each
