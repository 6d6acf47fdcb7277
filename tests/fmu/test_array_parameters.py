"""FMI 3.0 array parameters set by element (``A[1,2]``), as actions and observations name them.

``strict_arrays`` (bridge/models/strict.py) has a fixed 2 x 2 parameter array ``A`` (identity
until set) and the local ``det_A``, its determinant, and it refuses every get or set that is not
a whole-array call: elements given at initialisation are merged over the array's current values.
Before, ``A[1,1]`` passed ``check`` and the model then refused it as "not a variable".
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.batch import BatchEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import VariableError
from bridge.experiment.config import parse_experiment
from bridge.fmu import Model
from bridge.models.strict import strict_arrays_fmu
from bridge.plant.system.plant import SystemPlant

ELEMENTS = {"A[1,1]": 2.0, "A[1,2]": 1.0, "A[2,1]": 3.0}  # A = [[2, 1], [3, 1]]: det -1
DET = -1.0


@pytest.fixture(scope="module")
def fmu() -> Path:
    return strict_arrays_fmu()


@pytest.mark.parametrize("policy", ["auto", "reset", "restore", "reinstantiate"])
def test_array_elements_as_parameters_under_every_reset_policy(fmu: Path, policy: str) -> None:
    with Model(fmu, reset_policy=policy) as model:  # type: ignore[arg-type]
        model.initialize(ELEMENTS)
        assert model.get(["A"])["A"].tolist() == [[2.0, 1.0], [3.0, 1.0]]
        cases: list[tuple[dict[str, Any], float]] = [
            ({"A[2,2]": 5.0}, 5.0),
            (ELEMENTS, DET),
            ({"A": [[1, 2], [3, 4]]}, -2.0),
        ]
        for values, det in cases * 2:
            model.advance(2)
            model.reset(values)
            assert model.get(["det_A"])["det_A"] == det


def test_array_elements_refused_with_what_is_allowed(fmu: Path) -> None:
    with Model(fmu) as model:
        with pytest.raises(VariableError, match=r"'A\[3,1\]': index out of range .* 'A\[1,1\]'"):
            model.initialize({"A[3,1]": 1.0})
        with pytest.raises(VariableError, match=r"'A' is an array of shape \(2, 2\) .* got 3 values"):
            model.initialize({"A": [1.0, 2.0, 3.0]})
        with pytest.raises(VariableError, match=r"'A' of strict_arrays is given both whole and by element"):
            model.initialize({"A": [1.0, 0.0, 0.0, 1.0], "A[1,1]": 2.0})


def experiment(fmu: Path, tmp_path: Path, **model: Any) -> dict[str, Any]:
    data = {
        "model": {
            "fmu": str(fmu),
            "step_size": 0.1,
            "sampling_time": 0.1,
            "episode_duration": 1.0,
            "parameters": ELEMENTS,
            **model,
        },
        "actions": {"inputs": ["u[1]"], "low": {"u[1]": 0.0}, "high": {"u[1]": 2.0}},
        "observations": {"outputs": ["det_A", "total"], "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(data))
    return data


@pytest.mark.parametrize("interface", ["cs", "me"])
def test_env_sets_array_elements_of_model_parameters(fmu: Path, tmp_path: Path, interface: str) -> None:
    exp = parse_experiment(experiment(fmu, tmp_path, interface=interface), source=tmp_path / "a.yaml")
    with FmuEnv(exp) as env:
        for seed in (0, 1):
            obs, _ = env.reset(seed=seed)
            assert obs[0] == DET
            obs, *_ = env.step(np.zeros(1, dtype=np.float32))
            assert obs[0] == DET


def test_batch_env_sets_array_elements_of_model_parameters(fmu: Path, tmp_path: Path) -> None:
    exp = parse_experiment(experiment(fmu, tmp_path), source=tmp_path / "a.yaml")
    env = BatchEnv(exp, 2)
    try:
        obs = env.reset_all([0, 1])[0]
        assert obs[:, 0].tolist() == [DET, DET]
        obs = env.step(np.zeros((2, 1), dtype=np.float32))[0]
        assert obs[:, 0].tolist() == [DET, DET]
    finally:
        env.close()


def test_system_component_sets_array_elements_of_its_parameters(fmu: Path, tmp_path: Path) -> None:
    data = {
        "system": {
            "components": {"a": {"fmu": str(fmu), "parameters": ELEMENTS}, "b": {"fmu": str(fmu)}},
            "connections": ["a.total -> b.u[1]"],
        },
        "model": {"step_size": 0.1, "sampling_time": 0.1, "episode_duration": 1.0},
        "actions": {"inputs": ["a.u[1]"], "low": {"a.u[1]": 0.0}, "high": {"a.u[1]": 2.0}},
        "observations": {"outputs": ["a.det_A", "b.det_A"], "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    exp = parse_experiment(data, source=tmp_path / "s.yaml")
    with SystemPlant(exp) as plant:
        plant.bind(["a.u[1]"], ["a.det_A", "b.det_A"])
        for _ in range(2):
            assert plant.reset({}, [1.0]).tolist() == [DET, 1.0]
            assert plant.step([1.0]).tolist() == [DET, 1.0]


@pytest.mark.integration
def test_isolated_plant_sets_array_elements_of_model_parameters(fmu: Path, tmp_path: Path) -> None:
    data = experiment(fmu, tmp_path, isolation={"timeout": 60.0})
    exp = parse_experiment(data, source=tmp_path / "a.yaml")
    with FmuEnv(exp) as env:
        assert env.unwrapped.plant.isolated  # type: ignore[attr-defined]
        for seed in (0, 1):
            obs, _ = env.reset(seed=seed)
            assert obs[0] == DET


def test_what_a_node_reports_keeps_which_start_values_may_be_set(fmu: Path) -> None:
    """Before, a node's model summary dropped ``initial``: a remote env refused start values of
    ``x`` (a local with initial exact) that the in-process env takes."""
    import json

    from bridge.fmu import read_model_info
    from bridge.fmu.vocab import info_from_summary, summary_of

    info = read_model_info(fmu)
    again = info_from_summary(json.loads(json.dumps(summary_of(info))))
    for name, var in info.variables.items():
        assert again.variables[name].initial == var.initial
        assert again.variables[name].settable_at_init == var.settable_at_init
    assert again.variables["x"].settable_at_init
