"""The native macro step equals the Python master bit for bit, and steps aside where it cannot serve."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.errors import BridgeError
from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant

EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"
OUTPUTS = ["load.omega", "motor.omega", "motor.current", "controller.u", "load.torque"]


def example(tmp_path: Path, **system: Any) -> Any:
    data = yaml.safe_load(EXAMPLE.read_text())
    data["system"].update(system)
    return parse_experiment(data, source=tmp_path / "system.yaml")


def run(exp: Any, steps: int = 150) -> tuple[np.ndarray, bool]:
    """Observations over ``steps`` samples with a varying set-point, and whether the native step ran."""
    with SystemPlant(exp) as plant:
        plant.bind(["controller.reference"], OUTPUTS)
        rows = [plant.reset({}, [0.0])]
        rows += [plant.step([20.0 + 10.0 * np.sin(0.05 * i)]) for i in range(steps)]
        rows.append(np.array(list(plant.component_values())))
        native = plant.master.native is not None
    return np.array(rows[:-1]), native


@pytest.mark.parametrize("iterations", [1, 4])
@pytest.mark.parametrize("outputs", ["held", "updated"])
@pytest.mark.parametrize("algorithm", ["jacobi", "gauss_seidel"])
def test_the_native_master_equals_the_python_master_bit_for_bit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, algorithm: str, outputs: str, iterations: int
) -> None:
    """The example system: three FMUs, the motor multi-rate (two FMU steps per macro step); with
    ``feedthrough_outputs: updated`` the feedthrough components settled in the native call too,
    with fixed-point iteration the states saved and restored there."""
    iteration = {"iteration": {"max_iterations": iterations}} if iterations > 1 else {}
    exp = example(tmp_path, algorithm=algorithm, feedthrough_outputs=outputs, **iteration)
    native, used = run(exp)
    assert used
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")  # the Python master over native samples
    python, used = run(exp)
    assert not used
    np.testing.assert_array_equal(native, python)
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE", "1")  # the Python master and Python FMI calls
    np.testing.assert_array_equal(native, run(exp)[0])
    assert np.max(np.abs(native[:, 0])) > 10.0


def cartpole(tmp_path: Path, sampling_s: float = 0.02) -> Any:
    data = {
        "model": {"step_size": 0.02, "sampling_time": sampling_s, "episode_duration": 10.0},
        "system": {
            "components": {
                "gain": {"fmu": "example:feedthrough"},
                "cart": {"fmu": "example:cartpole", "parameters": {"track_limit": 0.5}},
            },
            "connections": ["gain.y -> cart.force"],
        },
        "actions": {"inputs": ["gain.u"], "low": {"gain.u": -10.0}, "high": {"gain.u": 10.0}},
        "observations": {"outputs": ["cart.x", "cart.theta"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    return parse_experiment(data, source=tmp_path / "cart.yaml")


def push(exp: Any, force: float) -> tuple[list[np.ndarray], bool, float, bool]:
    with SystemPlant(exp) as plant:
        plant.bind(["gain.u"], ["cart.x", "cart.theta"])
        rows = [plant.reset({}, [force])]
        while not plant.terminated and plant.time_s < 5.0:
            rows.append(plant.step([force]))
        return rows, plant.terminated, plant.time_s, plant.master.native is not None


@pytest.mark.parametrize("sampling_s", [0.02, 0.1])
def test_a_component_that_asks_to_stop_stops_the_system_alike(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sampling_s: float
) -> None:
    """The cart leaves its track (terminate request), also within a sample of five macro steps:
    the same macro step, time and values both ways."""
    rows, terminated, t, used = push(cartpole(tmp_path, sampling_s), 10.0)
    assert used and terminated and 0.2 < t < 5.0
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python_rows, python_terminated, python_t, used = push(cartpole(tmp_path, sampling_s), 10.0)
    assert not used and python_terminated and python_t == t
    np.testing.assert_array_equal(np.array(rows), np.array(python_rows))


def test_a_non_finite_input_is_refused_as_in_python(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def fail() -> str:
        with SystemPlant(cartpole(tmp_path)) as plant:
            plant.bind(["gain.u"], ["cart.x"])
            plant.reset({}, [0.0])
            with pytest.raises(Exception) as info:
                plant.step([float("nan")])
            return f"{type(info.value).__name__}: {info.value}"

    native = fail()
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    assert native == fail() and "nan" in native.lower()


def episodes(exp: Any) -> tuple[list[Any], bool]:
    """Two episodes, a sample with no new inputs (the last held), the clocks and sample counts of
    each component after each, and what stepping a terminated system says."""
    seen: list[Any] = []
    with SystemPlant(exp) as plant:
        plant.bind(["gain.u"], ["cart.x", "cart.theta"])
        for force in (3.0, -4.0):
            seen.append(plant.reset({}, [force]))
            seen += [plant.step([force]), plant.step(None), plant.step(np.array([force / 2]))]
            seen.append([(n, p.sample, p.model.step_index, p.model.time_s) for n, p in plant.plants.items()])  # type: ignore[attr-defined]
            seen.append((plant.sample, plant.time_s))
        while not plant.terminated:
            plant.step([10.0])
        with pytest.raises(Exception) as info:
            plant.step([10.0])
        seen.append(f"{type(info.value).__name__}: {info.value}")
        used = plant.master.native is not None
    return seen, used


@pytest.mark.parametrize("sampling_s", [0.02, 0.06])
def test_the_native_sample_counts_and_resets_as_the_python_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sampling_s: float
) -> None:
    """The task's inputs set and the observation gathered in the native call: the same values,
    per-component step counters and sample counts, over a reset, and the same refusal after the
    system terminated."""
    native, used = episodes(cartpole(tmp_path, sampling_s))
    assert used
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python, used = episodes(cartpole(tmp_path, sampling_s))
    assert not used
    assert len(native) == len(python)
    for ours, reference in zip(native, python):
        if isinstance(ours, np.ndarray):
            np.testing.assert_array_equal(ours, reference)
        else:
            assert ours == reference
    assert "terminat" in native[-1].lower()


def test_the_native_sample_refuses_inputs_of_the_wrong_length(tmp_path: Path) -> None:
    with SystemPlant(cartpole(tmp_path)) as plant:
        plant.bind(["gain.u"], ["cart.x"])
        plant.reset({}, [0.0])
        assert plant.master.native is not None
        with pytest.raises(BridgeError, match="expected 1 numbers, got 2"):
            plant.step([1.0, 2.0])
        with pytest.raises(BridgeError, match="expected 1 numbers, got 2"):
            plant.step(np.array([1.0, 2.0]))
        with pytest.raises(BridgeError, match="expected 1 numbers, got 1"):
            plant.step(["fast"])  # type: ignore[list-item]
