"""An FMU that declares canBeInstantiatedOnlyOncePerProcess (models/global_state: its integral is a
static of the library) never has two instances in one process: FmuEnv, the vector envs over it and a
system's components put each instance in its own process and give what one instance per process
gives; a batch env and a second in-process instance are refused with the reason."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from bridge.env.batch import BatchEnv, BatchVectorEnv
from bridge.env.fmu_env import FmuEnv
from bridge.env.vec import PlantVecEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, load_experiment
from bridge.fmu import read_model_info
from bridge.models import example_fmu
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant

H = 0.1
STEPS = 6


def experiment(tmp_path: Path) -> Experiment:
    path = tmp_path / "global_state.yaml"
    path.write_text(
        f"model: {{fmu: '{example_fmu('global_state')}', step_size: {H}, episode_duration: 1.0}}\n"
        "actions: {inputs: [u], low: {u: -1}, high: {u: 1}}\n"
        "observations: {outputs: [y], scale: none}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return load_experiment(path)


def inputs(i: int) -> np.ndarray:
    """Env i's input at each step: different per env, so shared state shows."""
    return np.array([0.2 + 0.3 * i - 0.05 * k for k in range(STEPS)], dtype=np.float32)


def alone(i: int) -> np.ndarray:
    """y of one instance alone in its process: the integral of its own input (gain 1)."""
    return np.cumsum(inputs(i).astype(np.float64) * H).astype(np.float32)


def test_the_models_instances_in_one_process_share_its_state() -> None:
    """The model is a real test: loaded twice in one process (FMPy, no fmu-bridge), it goes wrong."""
    fmu = example_fmu("global_state")
    md = read_model_description(str(fmu))
    assert md.coSimulation.canBeInstantiatedOnlyOncePerProcess
    assert read_model_info(fmu).once_per_process
    unzipped = extract(str(fmu))
    try:
        slaves = []
        for n in range(2):
            slave = FMU2Slave(
                guid=md.guid, unzipDirectory=unzipped, modelIdentifier="global_state", instanceName=f"i{n}"
            )
            slave.instantiate()
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            slave.exitInitializationMode()
            slaves.append(slave)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        ys = np.zeros((STEPS, 2))
        for k in range(STEPS):
            for n, slave in enumerate(slaves):
                slave.setReal([vr["u"]], [float(inputs(n)[k])])
                slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
                ys[k, n] = slave.getReal([vr["y"]])[0]
        for slave in slaves:
            slave.terminate()
            slave.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    assert not np.allclose(ys[:, 0], alone(0)), "two instances in one process did not disturb each other"


def run(envs: list[FmuEnv]) -> np.ndarray:
    for env in envs:
        env.reset(seed=0)
    ys = np.zeros((STEPS, len(envs)), dtype=np.float32)
    for k in range(STEPS):
        for i, env in enumerate(envs):
            ys[k, i] = env.step(inputs(i)[k : k + 1])[0][0]
    return ys


def test_fmu_envs_each_get_their_own_process_and_equal_one_instance_per_process(tmp_path: Path) -> None:
    exp = experiment(tmp_path)
    envs = [FmuEnv(exp) for _ in range(3)]
    try:
        assert all(isinstance(env.plant, IsolatedFmuPlant) for env in envs)
        pids = {env.plant._process.pid for env in envs}  # type: ignore[attr-defined]
        assert len(pids) == 3 and os.getpid() not in pids
        ys = run(envs)
    finally:
        for env in envs:
            env.close()
    for i in range(3):
        np.testing.assert_allclose(ys[:, i], alone(i), rtol=1e-6)


@pytest.mark.integration  # an FMU that runs once per process: each env's plant is a child process
def test_a_plant_vec_env_over_them_equals_one_instance_per_process(tmp_path: Path) -> None:
    exp = experiment(tmp_path)
    vec = PlantVecEnv([FmuEnv(exp) for _ in range(2)])
    try:
        vec.reset()
        ys = np.array(
            [vec.step(np.stack([inputs(i)[k : k + 1] for i in range(2)]))[0][:, 0] for k in range(STEPS)]
        )
    finally:
        vec.close()
    for i in range(2):
        np.testing.assert_allclose(ys[:, i], alone(i), rtol=1e-6)


def test_a_second_instance_in_this_process_is_refused_until_the_first_closes(tmp_path: Path) -> None:
    exp = experiment(tmp_path)
    first = LocalFmuPlant(experiment_plant_spec(exp))
    try:
        with pytest.raises(ConfigError, match=r"canBeInstantiatedOnlyOncePerProcess.*already open"):
            LocalFmuPlant(experiment_plant_spec(exp))
    finally:
        first.close()
    LocalFmuPlant(experiment_plant_spec(exp)).close()  # the first one gave the process back


def test_a_batch_env_of_several_is_refused_and_of_one_runs_alone(tmp_path: Path) -> None:
    exp = experiment(tmp_path)
    with pytest.raises(ConfigError, match=r"canBeInstantiatedOnlyOncePerProcess.*n_envs=1 per process"):
        BatchEnv(exp, 2)
    with pytest.raises(ConfigError, match="canBeInstantiatedOnlyOncePerProcess"):
        BatchVectorEnv(exp, 3)
    env = BatchVectorEnv(exp, 1)
    try:
        env.reset(seed=0)
        ys = [env.step(inputs(0)[k : k + 1].reshape(1, 1))[0][0, 0] for k in range(STEPS)]
    finally:
        env.close()
    np.testing.assert_allclose(ys, alone(0), rtol=1e-6)


def test_a_systems_components_of_it_each_get_a_process_and_equal_one_instance_per_process(
    tmp_path: Path,
) -> None:
    """Two components of the FMU, coupled a.y -> b.u (Jacobi), b with gain 2: each component runs in
    a child process of its own, and the outputs are what one instance per process gives."""
    path = tmp_path / "system.yaml"
    path.write_text(
        "system:\n"
        "  algorithm: jacobi\n"
        "  components:\n"
        "    a: {fmu: example:global_state}\n"
        "    b: {fmu: example:global_state, parameters: {gain: 2.0}}\n"
        "  connections:\n"
        "    - a.y -> b.u\n"
        f"model: {{step_size: {H}, episode_duration: 1.0}}\n"
        "actions: {inputs: [a.u], low: {a.u: -1}, high: {a.u: 1}}\n"
        "observations: {outputs: [a.y, b.y], scale: none}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    u = inputs(0).astype(np.float64)
    a_y = np.cumsum(u * H)  # a alone: the integral of its input, at the end of each step
    b_u = np.concatenate([[0.0], a_y[:-1]])  # Jacobi: b gets a.y at the start of the step
    b_y = np.cumsum(2.0 * b_u * H)
    env = FmuEnv(load_experiment(path))
    try:
        plants = env.plant.plants  # type: ignore[attr-defined]
        assert all(isinstance(p, IsolatedFmuPlant) for p in plants.values())
        env.reset(seed=0)
        children = {p._process.pid for p in plants.values()}
        assert len(children) == 2 and os.getpid() not in children
        observed = [env.step(inputs(0)[k : k + 1])[0] for k in range(STEPS)]
        np.testing.assert_allclose(np.array(observed), np.stack([a_y, b_y], axis=1), rtol=1e-6, atol=1e-9)
        env.reset(seed=1)  # a second episode starts from zero in both processes
        again = [env.step(inputs(0)[k : k + 1])[0] for k in range(STEPS)]
        np.testing.assert_allclose(np.array(again), np.array(observed), rtol=0, atol=0)
    finally:
        env.close()
