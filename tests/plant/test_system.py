"""A system of coupled FMUs against FMPy's SSP master and against one FMU with the same equations."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from ssp_files import ssd_text, write_ssp

from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant
from tests.conftest import example_fmu

MOTOR = {"J": 0.002, "voltage": 12.0}
LOAD = {"N": 5.0, "k": 50.0, "d": 0.5, "J": 0.05}


def motor_load_ssp(tmp_path: Path) -> Path:
    components = {
        "motor": (
            "resources/dcmotor.fmu",
            {"load_torque": "input", "omega": "output", "current": "output"},
            MOTOR,
        ),
        "load": (
            "resources/gearload.fmu",
            {"omega_in": "input", "torque": "output", "omega": "output"},
            LOAD,
        ),
    }
    connections = [("motor", "omega", "load", "omega_in"), ("load", "torque", "motor", "load_torque")]
    fmus = {
        "resources/dcmotor.fmu": example_fmu("dcmotor", "2.0", "cs"),
        "resources/gearload.fmu": example_fmu("gearload", "2.0", "cs"),
    }
    return write_ssp(tmp_path / "motor_load.ssp", ssd_text(components, connections), fmus)


def system_experiment(fmu: str, tmp: Path, step: float, duration: float, **system: Any) -> Any:
    data: dict[str, Any] = {
        "model": {"fmu": fmu, "step_size": step, "episode_duration": duration},
        "actions": {"inputs": ["load.tau_ext"], "low": {"load.tau_ext": -1.0}, "high": {"load.tau_ext": 1.0}},
        "observations": {"outputs": ["motor.omega", "motor.current", "load.omega", "load.torque"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    system.setdefault("components", {"motor": {"feedthrough": False}})
    data["system"] = system
    return parse_experiment(data, source=tmp / "experiment.yaml")


def run(plant: SystemPlant, steps: int) -> np.ndarray:
    plant.bind(["load.tau_ext"], ["motor.omega", "motor.current", "load.omega", "load.torque"])
    rows = [plant.reset({}, [0.0])]
    rows += [plant.step([0.0]) for _ in range(steps)]
    return np.array(rows)


def test_jacobi_matches_fmpy_simulate_ssp(tmp_path: Path) -> None:
    from fmpy.ssp.simulation import simulate_ssp

    ssp = motor_load_ssp(tmp_path)
    h, steps = 1e-3, 400
    parameters = [SimpleNamespace(name=f"motor.{k}", value=v) for k, v in MOTOR.items()]
    parameters += [SimpleNamespace(name=f"load.{k}", value=v) for k, v in LOAD.items()]
    reference = simulate_ssp(
        str(ssp),
        stop_time=steps * h - h / 2,
        step_size=h,
        parameter_set=SimpleNamespace(parameters=parameters),
    )
    with SystemPlant(system_experiment(str(ssp), tmp_path, h, 1.0)) as plant:
        ours = run(plant, steps)
    # FMPy's rows hold the values after each step, labelled with the step's start time.
    assert len(reference) == steps
    for column, name in enumerate(["motor.omega", "motor.current", "load.omega", "load.torque"]):
        np.testing.assert_allclose(ours[1:, column], reference[name], rtol=0, atol=1e-9, err_msg=name)
    assert np.max(np.abs(ours[:, 0])) > 10.0  # the motor really turned


def monolithic(h: float, steps: int) -> np.ndarray:
    from bridge.fmu import Model

    with Model(example_fmu("motor_gearload", "2.0", "cs"), step_size_s=h) as model:
        model.reset({"J_motor": MOTOR["J"], "voltage": 12.0, "N": 5.0, "k": 50.0, "d": 0.5, "J_load": 0.05})
        names = ["omega_motor", "current", "omega", "torque"]
        rows = [list(model.get(names).values())]
        for _ in range(steps):
            model.advance(1)
            rows.append(list(model.get(names).values()))
    return np.array(rows)


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss_seidel"])
def test_coupling_error_shrinks_first_order_with_the_macro_step(tmp_path: Path, algorithm: str) -> None:
    """Constant extrapolation of coupled values is first order: halving H halves the error."""
    ssp = motor_load_ssp(tmp_path)
    errors = []
    for h in (2e-3, 1e-3, 5e-4):
        steps = round(0.2 / h)
        exact = monolithic(h, steps)
        with SystemPlant(system_experiment(str(ssp), tmp_path, h, 1.0, algorithm=algorithm)) as plant:
            coupled = run(plant, steps)
        errors.append(np.max(np.abs(coupled[:, 0] - exact[:, 0])) / np.max(np.abs(exact[:, 0])))
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert errors[-1] < 5e-3, errors  # stated tolerance: 0.5 % of full scale at H = 0.5 ms
    assert all(1.7 < r < 2.3 for r in ratios), (errors, ratios)


def test_iteration_makes_the_coupling_implicit_and_more_accurate(tmp_path: Path) -> None:
    ssp = motor_load_ssp(tmp_path)
    h, steps = 2e-3, 100
    exact = monolithic(h, steps)
    with SystemPlant(system_experiment(str(ssp), tmp_path, h, 1.0)) as plant:
        explicit = run(plant, steps)
    it = {"max_iterations": 30, "tolerance": 1e-12}
    with SystemPlant(system_experiment(str(ssp), tmp_path, h, 1.0, iteration=it)) as plant:
        implicit = run(plant, steps)
        assert plant.master.unconverged_steps == 0
    err = [np.max(np.abs(x[:, 0] - exact[:, 0])) for x in (explicit, implicit)]
    assert err[1] < 0.8 * err[0], err  # measured 0.63: still first order, a smaller constant


def test_multirate_component_steps_are_whole_fmu_steps(tmp_path: Path) -> None:
    ssp = motor_load_ssp(tmp_path)
    comps = {"motor": {"feedthrough": False, "step_size": 2.5e-4}}
    with SystemPlant(system_experiment(str(ssp), tmp_path, 1e-3, 1.0, components=comps)) as plant:
        run(plant, 10)
        motor = plant.plants["motor"]
        assert motor.timing.steps_per_sample == 4
        assert motor.model.step_index == 40  # type: ignore[attr-defined]
        assert plant.time_s == pytest.approx(0.01, abs=1e-15)


def test_reset_replays_the_same_trajectory(tmp_path: Path) -> None:
    ssp = motor_load_ssp(tmp_path)
    with SystemPlant(system_experiment(str(ssp), tmp_path, 1e-3, 1.0)) as plant:
        first = run(plant, 50)
        second = run(plant, 50)
    np.testing.assert_array_equal(first, second)
