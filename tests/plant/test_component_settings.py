"""A system component takes every model key ``model:`` takes, with the same effect.

Before, ``system.components.NAME.solver`` (and ``tolerance``, ``reset_policy``, ``start_values``,
``solver_substeps``) was an unknown key, though ``model.solver`` was accepted: the two sections
now share one schema (:class:`bridge.experiment.model_settings.ModelSettings`) and a component
opens its FMU through the same description (:class:`bridge.fmu.ModelSpec`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.experiment.config import ModelSection, parse_experiment
from bridge.experiment.model_settings import EXPERIMENT_KEYS, ModelSettings
from bridge.experiment.system import ComponentSection
from bridge.fmu.opening import open_model
from bridge.fmu.spec import ModelSpec
from bridge.models.strict import strict_arrays_fmu, strict_reset_fmu
from bridge.plant.system.plant import SystemPlant

H = 0.1


def test_every_key_of_model_is_a_key_of_a_component_or_the_experiments_own() -> None:
    model_keys = set(ModelSection.model_fields)
    assert set(ModelSettings.model_fields) <= set(ComponentSection.model_fields)
    assert model_keys - set(ComponentSection.model_fields) == set(EXPERIMENT_KEYS)
    for key in ("solver", "tolerance", "reset_policy", "start_values", "solver_substeps"):
        assert key in ComponentSection.model_fields


def system(components: dict[str, Any], outputs: list[str], inputs: list[str]) -> dict[str, Any]:
    return {
        "system": {"components": components, "connections": []},
        "model": {"step_size": H, "sampling_time": H, "episode_duration": 2.0},
        "actions": {"inputs": inputs, "low": dict.fromkeys(inputs, 0.0), "high": dict.fromkeys(inputs, 2.0)},
        "observations": {"outputs": outputs, "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
    }


@pytest.mark.parametrize("key", EXPERIMENT_KEYS)
def test_a_component_given_an_experiment_key_is_told_where_it_belongs(key: str, tmp_path: Path) -> None:
    value: Any = {"timeout": 5.0} if key == "isolation" else {"resource": "x"} if key == "licence" else 1.0
    data = system({"a": {"fmu": str(strict_arrays_fmu()), key: value}}, ["a.total"], ["a.u[1]"])
    with pytest.raises(ConfigError, match=rf"{key} is a setting of the whole experiment.*model\.{key}"):
        parse_experiment(data, source=tmp_path / "s.yaml")


def test_component_solver_substeps_tolerance_and_start_values_equal_the_same_model_alone(
    tmp_path: Path,
) -> None:
    fmu = strict_arrays_fmu()
    settings = {
        "interface": "me",
        "solver": "rk4",
        "solver_substeps": 3,
        "tolerance": 1e-7,
        "start_values": {"x[2]": 4.0},
        "parameters": {"k": 0.5},
    }
    data = system({"a": {"fmu": str(fmu), **settings}}, ["a.total", "a.y[1,2]"], ["a.u[1]"])
    exp = parse_experiment(data, source=tmp_path / "s.yaml")
    with SystemPlant(exp) as plant:
        plant.bind(["a.u[1]"], ["a.total", "a.y[1,2]"])
        rows = []
        for _ in range(2):  # two episodes: the reset policy's path too
            rows.append(plant.reset({}, [1.0]))
            rows += [plant.step([1.0]) for _ in range(5)]
    spec = ModelSpec.of(
        fmu,
        step_size_s=H,
        interface="me",
        solver="rk4",
        solver_substeps=3,
        tolerance=1e-7,
        parameters={"k": 0.5},
        start_values={"x[2]": 4.0},
    )
    alone = []
    with open_model(spec) as model:
        for episode in range(2):
            (model.initialize if episode == 0 else model.reset)(spec.initial_values())
            model.set({"u[1]": 1.0})
            read = model.signals(["total", "y[1,2]"])
            alone.append(np.asarray(read.read()))
            for _ in range(5):
                model.advance(1)
                alone.append(np.asarray(read.read()))
    np.testing.assert_array_equal(np.asarray(rows), np.asarray(alone))  # bit for bit
    assert rows[0][1] == 4.0, "the start value reached the component"


@pytest.mark.parametrize(("policy", "second_episode_steps"), [("reinstantiate", 10), ("reset", 1)])
def test_component_reset_policy_reaches_its_model(
    tmp_path: Path, policy: str, second_episode_steps: int
) -> None:
    """strict_reset keeps its terminated flag through fmi reset: the policy shows in the episodes."""
    data = system(
        {"a": {"fmu": str(strict_reset_fmu()), "reset_policy": policy, "parameters": {"quirks": 1}}},
        ["a.x"],
        ["a.u"],
    )
    exp = parse_experiment(data, source=tmp_path / "s.yaml")
    lengths = []
    with SystemPlant(exp) as plant:
        plant.bind(["a.u"], ["a.x"])
        for _ in range(2):
            plant.reset({}, [0.5])
            steps = 0
            while not plant.terminated and steps < 20:
                plant.step([0.5])
                steps += 1
            lengths.append(steps)
    assert lengths == [10, second_episode_steps]
