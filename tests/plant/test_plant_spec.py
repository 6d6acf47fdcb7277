"""Plants from a description (``PlantSpec``): no experiment, no task; the env checks the task once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.validate import Timing
from bridge.fmu.spec import ModelSpec
from bridge.models import example_fmu
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant
from bridge.plant.spec import PlantSpec
from bridge.plant.system.component import FmuComponent, component_plant_spec
from bridge.plant.system.description import from_experiment

CARTPOLE = example_experiment("cartpole_continuous")
SYSTEM = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"


def outputs(
    plant: LocalFmuPlant | IsolatedFmuPlant | FmuComponent, inputs: list[float], steps: int
) -> np.ndarray:
    rows = [plant.reset({"m_pole": 0.2} if "cartpole" in plant.name else {}, inputs)]
    rows += [plant.step(inputs) for _ in range(steps)]
    return np.array(rows)


def test_a_plant_from_a_description_written_by_hand_steps_as_the_experiments() -> None:
    """The Python API describes a model without any experiment file: the plant needs none."""
    h = 0.02
    spec = PlantSpec(
        ModelSpec.of(example_fmu("cartpole"), step_size_s=h, start_time_s=0.0), Timing(h, 1, h, 0.0)
    )
    with (
        LocalFmuPlant(spec) as mine,
        LocalFmuPlant(experiment_plant_spec(load_experiment(CARTPOLE))) as theirs,
    ):
        for plant in (mine, theirs):
            plant.bind(["force"], ["x", "theta"])
        got, expected = outputs(mine, [3.0], 30), outputs(theirs, [3.0], 30)
        np.testing.assert_array_equal(got, expected)
        assert got[-1, 0] > 0.1  # the cart moved under the push
        assert mine.name.startswith("FMU cartpole") and mine.name.endswith(".fmu (in-process)")


def test_a_description_whose_grid_is_not_its_timings_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"model steps 0.01 s from 0.0 s, its timing 0.02 s from 0.0 s"):
        PlantSpec(ModelSpec.of("x.fmu", step_size_s=0.01, start_time_s=0.0), Timing(0.02, 1, 0.02, 0.0))


def test_the_env_checks_the_task_against_the_plant_it_is_given() -> None:
    """No plant checks a task: the env does, once, against ``plant.info``. (A plant given to the
    env with a task naming no variable of it was a ValueError "'theta' is not in list".)"""
    good = load_experiment(CARTPOLE)
    observed = good.observations.model_copy(update={"outputs": ["x", "thetaa"]})
    bad = good.model_copy(update={"observations": observed})
    plant = LocalFmuPlant(experiment_plant_spec(good))
    with pytest.raises(
        ConfigError, match=r"observations.outputs: 'thetaa' is not a variable of the FMU; did you mean"
    ):
        FmuEnv(bad, plant=plant)


@pytest.mark.integration
def test_an_isolated_component_runs_the_description_an_in_process_one_runs() -> None:
    """One isolated plant for an experiment's FMU and a system's component alike: the child runs
    the component's description, its own parameters (the motor's J) set at every reset."""
    experiment = load_experiment(SYSTEM)
    system = from_experiment(experiment)
    spec = component_plant_spec(system.components["motor"], 0.001, 0.0)
    names = (["voltage", "load_torque"], ["omega", "current"])
    without_j = spec.model.replace(parameters=())
    with FmuComponent(spec) as here, IsolatedFmuPlant(spec, timeout_s=60.0) as child:
        plain = LocalFmuPlant(PlantSpec(without_j, spec.timing))
        try:
            for plant in (here, child, plain):
                plant.bind(*names)
            expected, got = outputs(here, [12.0, 0.0], 20), outputs(child, [12.0, 0.0], 20)
            np.testing.assert_array_equal(got, expected)
            assert not np.array_equal(outputs(plain, [12.0, 0.0], 20), expected)  # J made a difference
            assert child.name.startswith("component 'motor' (dcmotor") and child.name.endswith(
                ", child process)"
            )
        finally:
            plain.close()
