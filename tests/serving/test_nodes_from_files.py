"""Nodes composed from files (``bridge.serving``): a component's node runs the component's own
description, with no experiment invented for it, and serves what its system needs of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.net.system_node import NodeComponents
from bridge.plant.factory import fmu_plant
from bridge.plant.system.component import FmuComponent, component_plant_spec
from bridge.plant.system.description import from_experiment
from bridge.plant.system.plant import SystemPlant, system_timing
from bridge.serving.system import serve_components, served_components
from tests.conftest import Loopback

EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"


def observing_a_connected_input(directory: Path, node: str | None) -> Path:
    """The example system whose task also observes ``motor.voltage``, an input of the motor that
    the controller drives (a connection); with ``node``, the motor is served by that node."""
    data = yaml.safe_load(EXAMPLE.read_text())
    data["observations"]["outputs"].append("motor.voltage")
    if node is not None:
        data["system"]["components"]["motor"]["node"] = node
    path = directory / f"observed_{node or 'here'}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_component_node_runs_the_components_own_description(tmp_path: Path) -> None:
    experiment = load_experiment(observing_a_connected_input(tmp_path, "motor-node"))
    system = from_experiment(experiment)
    t = system_timing(experiment, system)
    served = served_components(experiment)["motor-node"]
    own = component_plant_spec(system.components["motor"], t.step_size_s, t.start_time_s, system.where)
    assert served.plant == own  # what an in-process component is built from, nothing invented
    assert served.plant.component == "motor" and served.served.timing == own.timing
    assert dict(served.plant.model.parameters) == {"J": 0.002}


def test_a_component_node_serves_a_connected_input_the_task_observes(tmp_path: Path) -> None:
    """The task observes a connected input of a served component: its node reads it back as it
    was written. (Served from an invented experiment, the node refused to start: "'voltage' is
    an input of the FMU".)"""
    experiment = load_experiment(observing_a_connected_input(tmp_path, "motor-node"))
    served = served_components(experiment)["motor-node"]
    names = served.served
    assert "voltage" in names.input_names and "voltage" in names.output_names
    node_plant = fmu_plant(served.plant)
    here = FmuComponent(served.plant)
    try:
        node_plant.bind(names.input_names, names.output_names)
        here.bind(names.input_names, names.output_names)
        inputs = [12.0 if n == "voltage" else 0.0 for n in names.input_names]
        np.testing.assert_array_equal(node_plant.reset({}, inputs), here.reset({}, inputs))
        for _ in range(5):
            got, expected = node_plant.step(inputs), here.step(inputs)
            np.testing.assert_array_equal(got, expected)
        assert got[list(names.output_names).index("voltage")] == 12.0
        assert got[list(names.output_names).index("omega")] > 0.0  # the motor turns under 12 V
    finally:
        node_plant.close()
        here.close()


def trajectory(env: FmuEnv, seed: int, steps: int = 20) -> np.ndarray:
    obs, info = env.reset(seed=seed)
    rows = [np.append(obs, info["time_s"])]
    for i in range(steps):
        obs, reward, _, _, info = env.step(np.array([0.7 * np.sin(0.3 * i)], dtype=np.float32))
        rows.append(np.append(obs, [reward, info["time_s"]]).astype(np.float64))
    return np.concatenate(rows)


@pytest.mark.integration
def test_a_system_observing_a_served_components_input_equals_the_in_process_system(
    loopback: Loopback, tmp_path: Path
) -> None:
    here = observing_a_connected_input(tmp_path, None)
    there = observing_a_connected_input(tmp_path, "observed-motor")
    nodes = serve_components(load_experiment(there), session=loopback.session, prefix=loopback.prefix)
    try:
        remote = NodeComponents(session=loopback.session, prefix=loopback.prefix, timeout_s=60.0)
        plant = SystemPlant(load_experiment(there), remote=remote)
        with FmuEnv(here) as local, FmuEnv(there, plant=plant) as distributed:
            assert type(distributed.plant.plants["motor"]).__name__ == "RemotePlant"  # type: ignore[attr-defined]
            for seed in (0, 1):
                expected, got = trajectory(local, seed), trajectory(distributed, seed)
                np.testing.assert_array_equal(got, expected)
            assert np.max(np.abs(expected)) > 1.0
    finally:
        for node in nodes:
            node.close()
