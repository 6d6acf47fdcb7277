"""The native master carries linear transformations and unit conversions (one affine map per link):
equal to the Python master bit for bit and to libcosim; ``system inspect`` says which master runs."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant
from tests.plant.ssp_semantics import motor_load, unit, write
from tests.plant.test_system_ssp_semantics import LINEAR_TORQUE, NAMES, STEPS, H, libcosim, same

UNITS = unit("rad/s", rad=1, s=-1) + unit("rpm", factor=2 * math.pi / 60, rad=1, s=-1)


def transformed(tmp_path: Path) -> Path:
    """Motor and load with the speed converted rad/s -> rpm and the torque through 0.5 x + 0.01."""
    text = motor_load(torque=LINEAR_TORQUE, units=UNITS, omega_unit=("rad/s", "rpm"))
    return write(tmp_path / "transformed.ssp", text)


def experiment(ssp: Path) -> Any:
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": NAMES},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    return parse_experiment(data, source=ssp.parent / "e.yaml")


def run(ssp: Path) -> tuple[np.ndarray, bool]:
    with SystemPlant(experiment(ssp)) as plant:
        plant.bind([], NAMES)
        rows = [plant.reset({}, None)] + [plant.step(None) for _ in range(STEPS)]
        return np.array(rows), plant.master.native is not None


def test_transformations_and_units_run_natively_equal_to_python_and_libcosim(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ssp = transformed(tmp_path)
    native, used = run(ssp)
    assert used  # before, any transformation or unit conversion selected the Python master
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python, used = run(ssp)
    assert not used
    np.testing.assert_array_equal(native, python)
    # libcosim does not convert SSD units: the same system with the conversion written out
    factor = 1 / (2 * math.pi / 60)
    explicit = motor_load(omega=f'<ssc:LinearTransformation factor="{factor!r}"/>', torque=LINEAR_TORQUE)
    same(native, libcosim(write(tmp_path / "explicit.ssp", explicit)))
    assert np.max(np.abs(native[:, 0])) > 10.0  # the motor really turned


def test_inspect_shows_each_links_map_and_which_master_runs(tmp_path: Path) -> None:
    from bridge.cli.system import _experiment, summary
    from bridge.plant.system.native_master import python_master_reason

    with SystemPlant(_experiment(transformed(tmp_path), no_feedthrough=["motor"])) as plant:
        data = summary(plant)
    omega, torque = data["links"]
    assert omega["units"] == {"from": "rad/s", "to": "rpm"} and omega["transformation"] is None
    assert omega["map"] == f"{60 / (2 * math.pi)!r} * value + 0.0"
    assert torque["transformation"]["kind"] == "LinearTransformation" and torque["units"] is None
    assert torque["map"] == "0.5 * value + 0.01"
    assert data["master"]["runs"] == "native"
    with SystemPlant(_experiment(transformed(tmp_path), iterations=3)) as plant:
        assert summary(plant)["master"]["runs"] == "native"  # iteration too
    with SystemPlant(_experiment(transformed(tmp_path), no_feedthrough=["motor"])) as plant:
        reason = python_master_reason(plant.system, {**plant.plants, "load": object()}, {}, plant.infos)
    assert reason == "component 'load' runs in a child process"


def test_the_python_master_is_named_for_a_table_mapping(tmp_path: Path) -> None:
    """A mapping transformation is a table, which the C loop does not carry: the reason names it."""
    from bridge.plant.system.native_master import python_master_reason
    from bridge.plant.system.structure import Connection, Endpoint, SystemDescription, Transform

    def table(value: float) -> float:
        return value

    c = Connection(Endpoint("a", "k"), Endpoint("b", "n"), Transform("IntegerMappingTransformation"))
    system = SystemDescription(components={}, connections=())
    assert python_master_reason(system, {}, {c: table}, {}) == (
        "connection a.k -> b.n maps values through a table (IntegerMappingTransformation)"
    )


@pytest.mark.parametrize("native", [True, False])
def test_a_connected_input_is_observed_as_the_value_it_held(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, native: bool
) -> None:
    """Before: `'load.omega_in' is an input of the FMU` (refused). Now it reads what the component
    was given for the macro step just done: its source's output of the step before, through the
    connection's map (rad/s -> rpm, 0.5 x + 0.01), on either master."""
    if not native:
        monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    names = ["motor.omega", "load.omega_in", "load.torque", "motor.load_torque"]
    data: dict[str, Any] = {
        "model": {"fmu": str(transformed(tmp_path)), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": names},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        plant.bind([], names)
        rows = np.array([plant.reset({}, None)] + [plant.step(None) for _ in range(50)])
        assert (plant.master.native is not None) == native
    rpm = 1 / (2 * math.pi / 60)
    np.testing.assert_allclose(rows[1:, 1], rpm * rows[:-1, 0], rtol=1e-15, atol=0)
    np.testing.assert_allclose(rows[1:, 3], 0.5 * rows[:-1, 2] + 0.01, rtol=1e-15, atol=0)
    assert rows[-1, 1] > 10.0  # the motor turned


def test_an_algebraic_loop_iterated_natively_equals_the_python_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both FMUs feedthrough (no --no-feedthrough): the loop through the unit conversion and the
    transformation is solved by fixed-point iteration, states saved and restored in the native
    call; the trajectory, the passes of the last step and the unconverged steps as in Python."""

    def iterated() -> tuple[np.ndarray, bool, int, int]:
        data: dict[str, Any] = {
            "model": {"fmu": str(transformed(tmp_path)), "step_size": H, "episode_duration": 1.0},
            "observations": {"outputs": NAMES},
            "system": {"iteration": {"max_iterations": 6, "tolerance": 1e-12}},
        }
        with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
            plant.bind([], NAMES)
            rows = np.array([plant.reset({}, None)] + [plant.step(None) for _ in range(60)])
            master = plant.master
            return rows, master.native is not None, master.last_iterations, master.unconverged_steps

    native = iterated()
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python = iterated()
    assert native[1] and not python[1]  # before, iteration always selected the Python master
    np.testing.assert_array_equal(native[0], python[0])
    assert native[2:] == python[2:] and native[2] > 1
