"""A distributed system whose component FMUs exist only where their nodes run (real Zenoh, 127.0.0.1).

The nodes serve FMU copies in one directory; the trainer's system file lives in another where
those paths do not exist. The system is described from the nodes' info replies (the same
variables and fingerprint as from the files), steps like the in-process system, with and without
fixed-point iteration, and an agent trains on it.
"""

from __future__ import annotations

import shutil
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
from bridge.plant.factory import model_fingerprint, model_info_for
from bridge.plant.system.plant import describe_system
from tests.conftest import Loopback
from tests.plant.test_system_nodes import NODES, remote_env, serve, system_file, trajectory

pytestmark = pytest.mark.integration
FMUS = {"controller": "pi_controller", "motor": "dcmotor", "load": "gearload"}


def with_copies(path: Path, iteration: bool = False) -> Path:
    """``path`` with its components' FMUs at ``fmus/NAME.fmu`` next to it (relative paths)."""
    data = yaml.safe_load(path.read_text())
    for component, model in FMUS.items():
        data["system"]["components"][component]["fmu"] = f"fmus/{model}.fmu"
    if iteration:
        data["system"]["iteration"] = {"max_iterations": 6, "tolerance": 1e-13}
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def sites(net: Loopback, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    """(the nodes' directory, with the FMU copies; the trainer's directory, without them)."""
    nodes_dir, trainer_dir = tmp_path_factory.mktemp("node_site"), tmp_path_factory.mktemp("trainer_site")
    (nodes_dir / "fmus").mkdir()
    for model in FMUS.values():
        shutil.copy(example_fmu(model, "2.0", "cs"), nodes_dir / "fmus" / f"{model}.fmu")
    with serve(with_copies(system_file(nodes_dir, "served", NODES)), net):
        yield nodes_dir, trainer_dir


def remote(net: Loopback) -> NodeComponents:
    return NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)


def test_the_nodes_describe_what_the_files_would(sites: tuple[Path, Path], net: Loopback) -> None:
    nodes_dir, trainer_dir = sites
    there = load_experiment(with_copies(system_file(trainer_dir, "described", NODES)))
    assert not (trainer_dir / "fmus").exists()
    with pytest.raises(
        ConfigError, match=r"system.components.controller.fmu: .*fmus/pi_controller.fmu is not"
    ):
        describe_system(there)  # no network given: says which file is missing and who has it
    here = load_experiment(with_copies(system_file(nodes_dir, "described_here", NODES)))
    from_nodes, from_files = model_info_for(there, remote(net)), model_info_for(here)
    assert list(from_nodes.variables) == list(from_files.variables)
    assert "motor.omega" in from_nodes.variables
    assert [v.causality for v in from_nodes.variables.values()] == [
        v.causality for v in from_files.variables.values()
    ]
    assert model_fingerprint(there, remote(net))[1] == model_fingerprint(here)[1]


@pytest.mark.parametrize("iteration", [False, True], ids=["explicit", "iterated"])
def test_a_system_steps_with_no_component_fmu_on_this_machine(
    sites: tuple[Path, Path], net: Loopback, iteration: bool
) -> None:
    nodes_dir, trainer_dir = sites
    here = with_copies(system_file(nodes_dir, f"local_{iteration}", {}), iteration)
    there = with_copies(system_file(trainer_dir, f"remote_{iteration}", NODES), iteration)
    with FmuEnv(here) as local, remote_env(there, net) as distributed:
        assert not any(c.fmu.exists() for c in distributed.plant.system.components.values())  # type: ignore[attr-defined]
        np.testing.assert_array_equal(trajectory(distributed, 5, steps=10), trajectory(local, 5, steps=10))


@pytest.mark.slow
def test_an_agent_trains_on_a_system_whose_fmus_are_elsewhere(
    sites: tuple[Path, Path], net: Loopback
) -> None:
    from stable_baselines3 import PPO

    _, trainer_dir = sites
    there = with_copies(system_file(trainer_dir, "train", NODES))
    with remote_env(there, net) as env:
        model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
        model.learn(total_timesteps=64)
        assert model.num_timesteps >= 64
