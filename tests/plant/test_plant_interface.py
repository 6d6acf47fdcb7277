"""The Plant interface its users need: saved states, component values and answer readiness.

The master (rollback), the recorder (component values) and the vector env (answers in the order
they come) call these on any plant; a plant that cannot do a thing answers with its default: it
refuses to save with the reason, has no components, and is always ready.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant

OUTPUTS = ["x", "x_dot", "theta", "theta_dot"]
REFUSED = r"\(child process\) cannot save and restore its state: it does not"


def test_a_plant_that_cannot_save_refuses_with_its_reason() -> None:
    experiment = load_experiment(example_experiment("cartpole_balance"))
    with IsolatedFmuPlant(experiment_plant_spec(experiment)) as plant:
        assert not plant.can_save
        assert plant.save_refusal == "it does not save or restore its state"
        for call in (plant.save, lambda: plant.restore(None), lambda: plant.discard(None)):
            with pytest.raises(ConfigError, match=REFUSED):
                call()


def test_an_fmu_in_this_process_saves_and_restores_through_the_interface() -> None:
    with LocalFmuPlant(
        experiment_plant_spec(load_experiment(example_experiment("cartpole_balance")))
    ) as plant:
        plant.bind(["force"], OUTPUTS)
        plant.reset({"theta0": 0.05}, [0.0])
        assert plant.can_save and plant.save_refusal == ""
        saved = plant.save()
        first = [plant.step([10.0]).tolist() for _ in range(5)]
        plant.restore(saved)
        assert plant.sample == 0 and plant.time_s == 0.0
        again = [plant.step([10.0]).tolist() for _ in range(5)]
        plant.discard(saved)
        assert again == first


def test_a_single_model_has_no_components_and_is_always_ready() -> None:
    with LocalFmuPlant(
        experiment_plant_spec(load_experiment(example_experiment("cartpole_balance")))
    ) as plant:
        plant.bind(["force"], OUTPUTS)
        plant.reset({}, [0.0])
        event = threading.Event()
        plant.notify_answers(event)
        plant.send([1.0])
        assert plant.answer_ready()
        assert plant.component_outputs() == {}
        assert plant.component_values().shape == (0,)
        assert np.isfinite(plant.receive()).all()
        assert not event.is_set()  # nothing to announce: the answer was computed in receive()
