"""Initialisation and typing of systems: algebraic loops at t0, String/Binary outputs, FMI 3.0 arrays."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant


def experiment(tmp_path: Path, components: dict[str, Any], connections: list[str], **extra: Any) -> Any:
    data: dict[str, Any] = {
        "model": {"step_size": 0.1, "episode_duration": 1.0},
        "system": {"components": components, "connections": connections, **extra.pop("system", {})},
        "observations": {"outputs": extra.pop("outputs")},
        "reward": {"terms": [{"alive": 0.0}]},
        **extra,
    }
    return parse_experiment(data, source=tmp_path / "system.yaml")


def controllers(ka: float, kb: float, ra: float, rb: float) -> dict[str, Any]:
    """Two proportional controllers, each measuring the other's output: u_a = ka (ra - u_b), ..."""
    return {
        "a": {"fmu": "example:pi_controller", "parameters": {"kp": ka, "ki": 0.0, "reference": ra}},
        "b": {"fmu": "example:pi_controller", "parameters": {"kp": kb, "ki": 0.0, "reference": rb}},
    }


LOOP = ["a.u -> b.measurement", "b.u -> a.measurement"]


@pytest.mark.parametrize(("ka", "kb", "ra", "rb"), [(0.5, 0.5, 1.0, 0.0), (0.8, -0.6, 2.0, 3.0)])
def test_an_algebraic_loop_starts_on_its_closed_form_solution(
    tmp_path: Path, ka: float, kb: float, ra: float, rb: float
) -> None:
    """u_a = ka (ra - kb rb) / (1 - ka kb) and u_b = kb (rb - u_a) solve the loop at t0."""
    iteration = {"max_iterations": 100, "tolerance": 1e-13}
    exp = experiment(
        tmp_path, controllers(ka, kb, ra, rb), LOOP, outputs=["a.u", "b.u"], system={"iteration": iteration}
    )
    ua = ka * (ra - kb * rb) / (1 - ka * kb)
    ub = kb * (rb - ua)
    with SystemPlant(exp) as plant:
        plant.bind([], ["a.u", "b.u"])
        start = plant.reset({}, None)
        np.testing.assert_allclose(start, [ua, ub], rtol=1e-11)
        np.testing.assert_allclose(plant.step(None), [ua, ub], rtol=1e-11)  # and stays there
        again = plant.reset({}, None)
    np.testing.assert_array_equal(start, again)


def test_an_algebraic_loop_without_iteration_is_refused_with_its_cycle(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        SystemPlant(experiment(tmp_path, controllers(0.5, 0.5, 1.0, 0.0), LOOP, outputs=["a.u"]))
    assert "algebraic loop: a.u -> b.measurement, b.u -> a.measurement" in str(info.value)


def test_string_and_binary_outputs_do_not_break_a_system(tmp_path: Path) -> None:
    """typed has a String output, typed3 a Binary one and a 2-D array: none read, all run."""
    components = {
        "t": {"fmu": "example:typed:2.0"},
        "t3": {"fmu": "example:typed3:3.0"},
    }
    exp = experiment(
        tmp_path,
        components,
        ["t.real_out -> t3.u[2]"],
        outputs=["t3.y[1,2]", "t3.y[1,1]"],
        actions={"inputs": ["t.real_in"], "low": {"t.real_in": -5.0}, "high": {"t.real_in": 5.0}},
    )
    with SystemPlant(exp) as plant:
        plant.bind(["t.real_in"], ["t3.y[1,2]", "t3.y[1,1]"])
        plant.reset({}, [1.5])
        plant.step([1.5])  # t copies real_in to real_out
        y12, y11 = plant.step([1.5])  # t3 got it in u[2] and holds it in y[1,2]
        recorded = plant.component_outputs()
    assert (y12, y11) == (1.5, 1.0)  # u[1] keeps its start value 1.0
    assert "string_out" not in recorded["t"] and "real_out" in recorded["t"]
    assert "data_out" not in recorded["t3"] and recorded["t3"]["y[1,2]"] == 1.5


def test_a_string_connection_is_refused(tmp_path: Path) -> None:
    components = {"a": {"fmu": "example:typed:2.0"}, "b": {"fmu": "example:typed:2.0"}}
    with pytest.raises(ConfigError) as info:
        SystemPlant(experiment(tmp_path, components, ["a.string_out -> b.string_in"], outputs=["a.real_out"]))
    message = str(info.value)
    assert "a.string_out is a String variable" in message and "not connected" in message


def test_a_scalar_connected_to_an_array_is_refused_with_both_shapes(tmp_path: Path) -> None:
    components = {"t": {"fmu": "example:typed:2.0"}, "t3": {"fmu": "example:typed3:3.0"}}
    with pytest.raises(ConfigError) as info:
        SystemPlant(experiment(tmp_path, components, ["t.real_out -> t3.u"], outputs=["t.real_out"]))
    message = str(info.value)
    for text in ("t.real_out is a scalar", "t3.u is an array of shape [3]", "t3.u[1]", "system.yaml"):
        assert text in message, message


def test_an_element_out_of_range_is_refused(tmp_path: Path) -> None:
    components = {"t": {"fmu": "example:typed:2.0"}, "t3": {"fmu": "example:typed3:3.0"}}
    with pytest.raises(ConfigError, match=r"index out of range for array u\[3\]"):
        SystemPlant(experiment(tmp_path, components, ["t.real_out -> t3.u[4]"], outputs=["t.real_out"]))


def motor_controller(tmp_path: Path, mode: str) -> Any:
    components = {
        "motor": {"fmu": "example:dcmotor", "feedthrough": False},
        "ctrl": {"fmu": "example:pi_controller", "parameters": {"kp": 0.5, "ki": 0.0, "reference": 10.0}},
    }
    return experiment(
        tmp_path,
        components,
        ["motor.omega -> ctrl.measurement", "ctrl.u -> motor.voltage"],
        outputs=["motor.omega", "ctrl.u"],
        system={"feedthrough_outputs": mode},
        model={"step_size": 0.001, "episode_duration": 1.0},
    )


def run_motor_controller(tmp_path: Path, mode: str) -> np.ndarray:
    with SystemPlant(motor_controller(tmp_path, mode)) as plant:
        plant.bind([], ["motor.omega", "ctrl.u"])
        rows = [plant.reset({}, None)] + [plant.step(None) for _ in range(200)]
    return np.array(rows)


def test_updated_feedthrough_outputs_are_of_one_instant(tmp_path: Path) -> None:
    """The controller's u = kp (reference - omega): updated, it is computed from omega at t + H."""
    updated = run_motor_controller(tmp_path, "updated")
    np.testing.assert_allclose(updated[:, 1], 0.5 * (10.0 - updated[:, 0]), rtol=0, atol=1e-12)
    held = run_motor_controller(tmp_path, "held")  # the default: u from omega at t, held over the step
    np.testing.assert_allclose(held[1:, 1], 0.5 * (10.0 - held[:-1, 0]), rtol=0, atol=1e-12)
    assert np.max(np.abs(held[:, 1] - 0.5 * (10.0 - held[:, 0]))) > 1e-3
    assert np.max(np.abs(updated[:, 0])) > 1.0


def test_an_initialisation_that_does_not_converge_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Loop gain 0.9 x 0.9: three sweeps are not enough for 1e-13; the plant says it did not converge."""
    iteration = {"max_iterations": 3, "tolerance": 1e-13}
    exp = experiment(
        tmp_path, controllers(0.9, 0.9, 1.0, 0.0), LOOP, outputs=["a.u"], system={"iteration": iteration}
    )
    with SystemPlant(exp) as plant:
        plant.bind([], ["a.u"])
        with caplog.at_level("WARNING"):
            plant.reset({}, None)
        assert not plant.master.init_converged
    assert "did not converge in 3 sweeps" in caplog.text and "system.yaml" in caplog.text


@pytest.fixture(scope="module")
def arrays3(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pythonfmu3's export of tests/data/slaves/Arrays3.py (u[3], k[3] in; y[2,3], n[3] out: n = k + 1)."""
    import subprocess
    import sys

    pytest.importorskip("pythonfmu3")
    slave = Path(__file__).resolve().parents[1] / "data" / "slaves" / "Arrays3.py"
    out = tmp_path_factory.mktemp("arrays3_system")
    cmd = [sys.executable, "-m", "pythonfmu3", "build", "-f", str(slave), "-d", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    if result.returncode != 0:
        pytest.fail(f"pythonfmu3 could not export Arrays3.py:\n{result.stdout}\n{result.stderr}")
    return out / "Arrays3.fmu"


def arrays_run(tmp_path: Path, fmu: Path, connections: list[str]) -> np.ndarray:
    components = {"a": {"fmu": str(fmu)}, "b": {"fmu": str(fmu)}}
    inputs = ["a.k[1]", "a.k[2]", "a.k[3]"]
    outputs = ["b.n[1]", "b.n[2]", "b.n[3]", "b.k[2]"]
    exp = experiment(
        tmp_path,
        components,
        connections,
        outputs=outputs[:3],
        actions={"inputs": inputs, "low": dict.fromkeys(inputs, -100), "high": dict.fromkeys(inputs, 100)},
    )
    with SystemPlant(exp) as plant:
        assert [str(c) for c in plant.system.connections] == [f"a.n[{i}] -> b.k[{i}]" for i in (1, 2, 3)]
        plant.bind(inputs, outputs)
        rows = [plant.reset({}, [0.0, 0.0, 0.0])]
        rows += [plant.step([float(i), 2.0 * i, -3.0 * i]) for i in range(1, 6)]
    return np.array(rows)


def test_whole_arrays_of_one_shape_connect_element_by_element(tmp_path: Path, arrays3: Path) -> None:
    """a.n -> b.k (both Int64 arrays of shape [3]): the run of the three element connections, and
    b.n = b.k + 1 with b.k the a.n = a.k + 1 of the macro step before."""
    whole = arrays_run(tmp_path, arrays3, ["a.n -> b.k"])
    by_element = arrays_run(tmp_path, arrays3, [f"a.n[{i}] -> b.k[{i}]" for i in (1, 2, 3)])
    np.testing.assert_array_equal(whole, by_element)
    from bridge.plant.system.description import from_experiment
    from bridge.serving.system import component_signals

    exp = parse_experiment(
        {
            "model": {"step_size": 0.1, "episode_duration": 1.0},
            "system": {
                "components": {"a": {"fmu": str(arrays3)}, "b": {"fmu": str(arrays3)}},
                "connections": ["a.n -> b.k"],
            },
            "observations": {"outputs": ["b.n[1]"]},
            "reward": {"terms": [{"alive": 0.0}]},
        },
        source=tmp_path / "node.yaml",
    )
    ins, _ = component_signals(exp, from_experiment(exp), "b")  # what b's node would serve
    _, outs = component_signals(exp, from_experiment(exp), "a")
    assert ins == ["k[1]", "k[2]", "k[3]"] and "n" not in outs and {"n[1]", "n[2]", "n[3]"} <= set(outs)
    for step in range(2, 6):
        k = np.array([step - 1, 2.0 * (step - 1), -3.0 * (step - 1)])  # a.k of the step before
        np.testing.assert_array_equal(whole[step, :3], k + 2.0)
        assert whole[step, 3] == k[1] + 1.0


def test_whole_arrays_of_different_shapes_are_refused_with_both(tmp_path: Path, arrays3: Path) -> None:
    components = {"a": {"fmu": str(arrays3)}, "b": {"fmu": str(arrays3)}}
    with pytest.raises(ConfigError) as info:
        SystemPlant(experiment(tmp_path, components, ["a.y -> b.u"], outputs=["b.n[1]"]))
    message = str(info.value)
    for text in (
        "a.y is an array of shape [2, 3]",
        "b.u is an array of shape [3]",
        "a.y[1] -> b.u[1]",
        "system.yaml",
    ):
        assert text in message, message
