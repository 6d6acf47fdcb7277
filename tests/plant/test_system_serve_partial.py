"""Serving some components of a system on a machine that holds only their FMUs (real Zenoh, 127.0.0.1).

The serving site has the motor's FMU and nothing else: ``system serve --component motor`` (in
this process and as the real command) works there, and a client whose site has every FMU steps
the whole system to the trajectory of the all-in-process run. Asking that site to serve a
component whose FMU it lacks is a clear error naming the file and ``--component``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.models import example_fmu
from bridge.net.system_node import NodeComponents
from bridge.net.transport import ZenohOptions, open_session
from bridge.plant.system.description import from_experiment, split_name
from bridge.plant.system.plant import SystemPlant, describe_system, system_timing
from bridge.serving.system import component_signals, serve_components
from bridge.task.core import Task
from tests.conftest import Loopback, _wait_for_node, free_port
from tests.plant.test_system_nodes import EXAMPLE, serve, trajectory

pytestmark = pytest.mark.integration
FMUS = {"controller": "pi_controller", "motor": "dcmotor", "load": "gearload"}
# names on every component, so that the node of one must take the others' as written
REWARD = {
    "terms": [{"signal": {"name": "motor.current", "norm": "squared", "weight": 0.001}}],
    "expression": "-0.01 * abs(load.omega - controller.reference) - 1e-4 * motor.torque**2",
}
BOUNDS = {"motor.omega": [-1000.0, 1000.0], "load.phi": [-1e6, 1e6]}


def site_file(directory: Path, models: list[str], nodes: dict[str, str], reward: dict | None = None) -> Path:
    """The example system at ``directory/system.yaml``, its FMUs at ``fmus/NAME.fmu`` (relative),
    of which only ``models`` are copied there; ``node:`` on the components in ``nodes``."""
    (directory / "fmus").mkdir(parents=True, exist_ok=True)
    for model in models:
        shutil.copy(example_fmu(model, "2.0", "cs"), directory / "fmus" / f"{model}.fmu")
    data = yaml.safe_load(EXAMPLE.read_text())
    for component, model in FMUS.items():
        data["system"]["components"][component]["fmu"] = f"fmus/{model}.fmu"
    for component, node in nodes.items():
        data["system"]["components"][component]["node"] = node
    data["reward"] = reward or REWARD
    data["termination"] = {"bounds": BOUNDS}
    path = directory / "system.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def sites(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(the motor's machine: only dcmotor.fmu, motor and load have node:; the client's: every FMU,
    only the motor in a node)."""
    motor_site = site_file(
        tmp_path_factory.mktemp("motor_site"), ["dcmotor"], {"motor": "motor-node", "load": "x"}
    )
    client = site_file(tmp_path_factory.mktemp("client_site"), list(FMUS.values()), {"motor": "motor-node"})
    assert not (motor_site.parent / "fmus" / "gearload.fmu").exists()
    assert not (motor_site.parent / "fmus" / "pi_controller.fmu").exists()
    return motor_site, client


@pytest.fixture
def client_session(net: Loopback) -> Iterator[Loopback]:
    """A session of its own (the client's machine), connected to the router, and a fresh prefix."""
    session = open_session(ZenohOptions(mode="client", connect=(net.endpoint,)))
    try:
        yield Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", session)
    finally:
        session.close()


def steps_like_in_process(client_file: Path, own: Loopback) -> None:
    local_file = client_file.parent / "local.yaml"
    data = yaml.safe_load(client_file.read_text())
    del data["system"]["components"]["motor"]["node"]
    local_file.write_text(yaml.safe_dump(data))
    remote = NodeComponents(session=own.session, prefix=own.prefix, timeout_s=60.0)
    plant = SystemPlant(load_experiment(client_file), remote=remote)
    with FmuEnv(local_file) as local, FmuEnv(client_file, plant=plant) as distributed:
        assert type(distributed.plant.plants["motor"]).__name__ == "RemotePlant"  # type: ignore[attr-defined]
        for seed in (1, 4):
            expected = trajectory(local, seed)
            np.testing.assert_array_equal(trajectory(distributed, seed), expected)
        assert np.max(np.abs(expected)) > 1.0  # the motor really turned


def test_the_motor_site_serves_its_node_in_process(
    sites: tuple[Path, Path], net: Loopback, client_session: Loopback
) -> None:
    motor_site, client = sites
    node_machine = ZenohOptions(mode="client", connect=(net.endpoint,))  # a session of the node's own
    nodes = serve_components(
        load_experiment(motor_site), ["motor"], options=node_machine, prefix=client_session.prefix
    )
    try:
        _wait_for_node(client_session, "motor-node", timeout_s=30)
        steps_like_in_process(client, client_session)
    finally:
        for node in nodes:
            node.close()


def test_the_motor_site_serves_its_node_from_the_command_line(
    sites: tuple[Path, Path], net: Loopback, client_session: Loopback
) -> None:
    motor_site, client = sites
    with serve(motor_site, client_session, "motor"):
        steps_like_in_process(client, client_session)


def test_the_node_serves_what_the_whole_task_names_on_it(sites: tuple[Path, Path]) -> None:
    """Against the names the task built over every component's FMU (the client's site) picks."""
    motor_site, client = sites
    full = load_experiment(client)
    system = from_experiment(full)
    task = Task(full, describe_system(full).variables, system_timing(full, system))
    on_motor = [
        e.variable
        for e in (split_name(n, system.components, "o") for n in task.output_names)
        if e.component == "motor"
    ]
    assert {"current", "torque", "omega"} <= set(on_motor)
    partial = load_experiment(motor_site)
    ins, outs = component_signals(partial, from_experiment(partial, check_files=False), "motor")
    assert ins == ["voltage", "load_torque"]
    assert outs == list(dict.fromkeys(["omega", "current", "torque", *on_motor]))


def test_a_typo_on_the_served_component_is_still_named(sites: tuple[Path, Path], tmp_path: Path) -> None:
    typo = {"expression": "-motor.curent**2 - abs(load.omega)"}
    file = site_file(tmp_path, ["dcmotor"], {"motor": "m", "load": "l"}, reward=typo)
    with pytest.raises(
        ConfigError, match=r"(?s)unknown name 'motor.curent'.*did you mean 'motor.current'"
    ) as caught:
        serve_components(load_experiment(file), ["motor"])
    assert "names: load.omega, motor.J" in str(caught.value)  # its own names and those spelled
    # a name on a component whose FMU is elsewhere is taken as written here; the client checks it
    other = site_file(
        tmp_path / "other", ["dcmotor"], {"motor": "m", "load": "l"}, {"expression": "-load.omegaa"}
    )
    system = from_experiment(load_experiment(other), check_files=False)
    assert component_signals(load_experiment(other), system, "motor")[1] == ["omega", "current", "torque"]


@pytest.mark.parametrize("chosen", [["load"], []], ids=["--component load", "every node component"])
def test_serving_a_component_whose_fmu_is_elsewhere_names_the_file(
    sites: tuple[Path, Path], chosen: list[str]
) -> None:
    motor_site, _ = sites
    missing = motor_site.parent / "fmus" / "gearload.fmu"
    with pytest.raises(ConfigError) as caught:
        serve_components(load_experiment(motor_site), chosen)
    message = str(caught.value)
    assert message.startswith("system.components.load.fmu: ") and str(missing) in message
    assert "--component NAME" in message and str(motor_site) in message


def test_the_command_names_the_missing_fmu_without_a_traceback(sites: tuple[Path, Path]) -> None:
    motor_site, _ = sites
    nobody = f"tcp/127.0.0.1:{free_port()}"  # the files are checked before the network is opened
    cmd = [sys.executable, "-m", "bridge.cli", "system", "serve", str(motor_site), "--connect", nobody]
    env = {**os.environ, "COLUMNS": "300"}
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, check=False)
    output = " ".join((done.stdout + done.stderr).split())
    assert done.returncode != 0, output
    assert "gearload.fmu" in output and "--component NAME" in output
    assert "Traceback" not in output and "Zenoh" not in output
    assert done.stderr.lstrip().startswith("error: system.components.load.fmu: ")


def test_two_served_components_on_one_node_name_are_refused(sites: tuple[Path, Path]) -> None:
    motor_site, _ = sites
    data = yaml.safe_load(motor_site.read_text())
    data["system"]["components"]["load"]["node"] = "motor-node"
    twice = motor_site.parent / "twice.yaml"
    twice.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"node names \['motor-node'\] are given to more than one"):
        serve_components(load_experiment(twice))
