"""BatchPlant: N typed-model instances, native and Python paths, per-instance errors and termination."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.errors import StepError
from bridge.experiment.config import load_experiment
from bridge.plant.batch import BatchPlant
from bridge.plant.experiment_model import experiment_plant_spec

TYPED = """\
model: {{fmu: 'example:typed:{version}', step_size: 0.1, sampling_time: 0.2, episode_duration: 5.0}}
actions: {{inputs: [real_in], low: {{real_in: -1}}, high: {{real_in: 1}}}}
observations: {{outputs: [real_out, real_integral, real_scaled]}}
reward: {{terms: [{{alive: 1.0}}]}}
"""
OUTPUTS = ["real_out", "real_integral", "real_scaled"]
H, N_STEPS = 0.1, 2  # FMU step; FMU steps per sample


@pytest.fixture(scope="module", params=["2.0", "3.0"])
def experiment(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("batch") / f"typed{request.param[0]}.yaml"
    text = TYPED.format(version=request.param)
    path.write_text(text)
    return path


def open_plant(path: Path, n: int, **kwargs: object) -> BatchPlant:
    plant = BatchPlant(experiment_plant_spec(load_experiment(path)), n, **kwargs)  # type: ignore[arg-type]
    plant.bind(["real_in"], OUTPUTS)
    return plant


def run(plant: BatchPlant, inputs: np.ndarray, values: list[dict[str, float]]) -> list[np.ndarray]:
    rows = []
    for i, v in enumerate(values):
        plant.reset(i, v, [0.0])
    for u in inputs:
        rows.append(plant.step(u).outputs.copy())
    return rows


@pytest.mark.parametrize("threads", [1, 2])
def test_native_and_python_paths_step_the_same_values(experiment: Path, threads: int) -> None:
    rng = np.random.default_rng(0)
    inputs = rng.uniform(-1, 1, size=(12, 5, 1))
    gains = [{"gain": float(g)} for g in rng.uniform(0.5, 3.0, size=5)]
    with open_plant(experiment, 5, native=True, threads=threads) as native:
        fast = run(native, inputs, gains)
        assert native.native
    with open_plant(experiment, 5, native=False) as python:
        slow = run(python, inputs, gains)
        assert not python.native
    np.testing.assert_array_equal(np.array(fast), np.array(slow))
    # independent reference: the typed model's equations (outputs copy, integral of u*h, gain*u)
    u = inputs[:, :, 0]
    integral = np.cumsum(u * H * N_STEPS, axis=0)
    np.testing.assert_allclose(np.array(fast)[:, :, 0], u)
    np.testing.assert_allclose(np.array(fast)[:, :, 1], integral, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.array(fast)[:, :, 2], u * np.array([g["gain"] for g in gains]))


@pytest.mark.parametrize("native", [True, False])
def test_a_failing_instance_ends_alone_and_resets(experiment: Path, native: bool) -> None:
    with open_plant(experiment, 4, native=native) as plant:
        values = [{}, {"fail_at_step": 3}, {}, {}]  # doStep 3 is in sample 2 (2 FMU steps a sample)
        for i, v in enumerate(values):
            plant.reset(i, v, [0.0])
        first = plant.step(np.full((4, 1), 0.5))
        assert first.errors == {}
        second = plant.step(np.full((4, 1), 0.25))
        assert list(second.errors) == [1]
        error = second.errors[1]
        assert isinstance(error, StepError)
        assert error.step == 2 and error.episode == 1
        assert "instance 1: the model failed at step 2 of episode 1 (t = 0.2 s)" in str(error)
        assert "fail_at_step reached" in str(error)
        np.testing.assert_array_equal(second.outputs[[0, 2, 3], 0], 0.25)
        third = plant.step(np.full((4, 1), 0.75))  # instance 1 no longer steps, the others do
        assert third.errors == {} and plant.k.tolist() == [6, 2, 6, 6]
        np.testing.assert_array_equal(third.outputs[[0, 2, 3], 0], 0.75)
        plant.reset(1, {}, [0.0])
        fourth = plant.step(np.full((4, 1), 1.0))
        assert fourth.errors == {} and plant.k.tolist() == [8, 2, 8, 8]
        np.testing.assert_array_equal(fourth.outputs[:, 0], 1.0)


@pytest.mark.parametrize("native", [True, False])
def test_termination_requested_by_one_instance_is_reported_for_it_only(
    experiment: Path, native: bool
) -> None:
    with open_plant(experiment, 3, native=native) as plant:
        for i, v in enumerate([{}, {"terminate_at_time": 0.3}, {}]):
            plant.reset(i, v, [0.0])
        assert plant.step(np.zeros((3, 1))).terminated.tolist() == [False, False, False]
        result = plant.step(np.zeros((3, 1)))  # the first FMU step ends at 0.2 + 0.1 > 0.3: stop there
        assert result.terminated.tolist() == [False, True, False]
        assert result.errors == {}
        assert plant.k.tolist() == [4, 3, 4]
        assert not plant.ready[1] and plant.ready[0]


def test_bad_sizes_are_config_errors(experiment: Path) -> None:
    from bridge.errors import ConfigError

    with pytest.raises(ConfigError, match="n >= 1"):
        BatchPlant(experiment_plant_spec(load_experiment(experiment)), 0)


@pytest.mark.parametrize("native", [True, False])
def test_the_batch_clock_is_each_models_own(experiment: Path, native: bool) -> None:
    with open_plant(experiment, 2, native=native) as plant:
        for i in range(2):
            plant.reset(i, {}, [0.0])
        for _ in range(3):
            plant.step(np.zeros((2, 1)), np.array([True, False]))
        assert plant.k.tolist() == [6, 0]
        assert [m.step_index for m in plant.models] == [6, 0]
        assert [m.time_s for m in plant.models] == [plant.time_s(0), plant.time_s(1)]
        assert plant.models[0].time_s == pytest.approx(6 * H)
