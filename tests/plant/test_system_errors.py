"""Bad systems fail before anything runs, naming the component, the variable and the file."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import pytest
from ssp_files import ssd_text, write_ssp

from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant
from tests.conftest import example_fmu


def experiment(tmp_path: Path, connections: list[str], **extra: Any) -> Any:
    components = {
        "motor": {"fmu": "example:dcmotor", "feedthrough": False},
        "load": {"fmu": "example:gearload"},
        "ctrl": {"fmu": "example:pi_controller"},
        "typed": {"fmu": "example:typed"},
    }
    data = {
        "model": {"step_size": 0.001, "episode_duration": 1.0},
        "system": {"components": components, "connections": connections, **extra},
        "actions": {"inputs": ["load.tau_ext"], "low": {"load.tau_ext": -1.0}, "high": {"load.tau_ext": 1.0}},
        "observations": {"outputs": ["motor.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=tmp_path / "system.yaml")


def fails(tmp_path: Path, connections: list[str], *expected: str, **extra: Any) -> str:
    with pytest.raises(ConfigError) as info:
        SystemPlant(experiment(tmp_path, connections, **extra))
    message = str(info.value)
    for text in (*expected, "system.yaml"):
        assert text in message, message
    return message


def test_unknown_component(tmp_path: Path) -> None:
    fails(tmp_path, ["motr.omega -> load.omega_in"], "'motr' is not a component", "motor")


def test_unknown_variable_suggests_close_names(tmp_path: Path) -> None:
    fails(
        tmp_path,
        ["motor.omegaa -> load.omega_in"],
        "'omegaa'",
        "component 'motor'",
        "did you mean",
        "'omega'",
    )


def test_output_to_output(tmp_path: Path) -> None:
    fails(tmp_path, ["motor.omega -> load.omega"], "load.omega", "output", "output -> output")


def test_input_driven_twice(tmp_path: Path) -> None:
    fails(
        tmp_path,
        ["motor.omega -> load.omega_in", "motor.current -> load.omega_in"],
        "load.omega_in",
        "already driven",
    )


def test_mismatched_types(tmp_path: Path) -> None:
    fails(tmp_path, ["motor.omega -> typed.boolean_in"], "Float64", "Boolean", "typed.boolean_in")


def test_units_of_different_quantities_are_refused(tmp_path: Path) -> None:
    """The FMUs define A and rad/s (UnitDefinitions): different SI base units, no conversion."""
    fails(tmp_path, ["motor.current -> load.omega_in"], "'A'", "'rad/s'", "different quantities")


def test_algebraic_loop_names_the_cycle(tmp_path: Path) -> None:
    loop = ["ctrl.u -> load.omega_in", "load.torque -> ctrl.measurement"]
    fails(tmp_path, loop, "algebraic loop", "ctrl.u -> load.omega_in", "load.torque -> ctrl.measurement")
    fails(tmp_path, loop, "gauss_seidel", algorithm="gauss_seidel")
    SystemPlant(experiment(tmp_path, loop, iteration={"max_iterations": 20})).close()  # solvable


def test_action_on_a_connected_input(tmp_path: Path) -> None:
    fails(
        tmp_path,
        ["typed.real_out -> load.tau_ext"],
        "actions.inputs",
        "load.tau_ext",
        "typed.real_out -> load.tau_ext",
    )


def test_missing_fmu_in_ssp_archive(tmp_path: Path) -> None:
    ssd = ssd_text({"motor": ("resources/dcmotor.fmu", {}, {}), "load": ("resources/gone.fmu", {}, {})}, [])
    ssp = write_ssp(
        tmp_path / "broken.ssp", ssd, {"resources/dcmotor.fmu": example_fmu("dcmotor", "2.0", "cs")}
    )
    data = {
        "model": {"fmu": "broken.ssp", "step_size": 0.001, "episode_duration": 1.0},
        "actions": {"inputs": ["load.tau_ext"]},
        "observations": {"outputs": ["motor.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    with pytest.raises(ConfigError) as info:
        SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml"))
    message = str(info.value)
    assert "'load'" in message and "resources/gone.fmu" in message and "missing in the SSP archive" in message
    assert str(ssp) in message


def test_ssp_that_is_not_a_zip(tmp_path: Path) -> None:
    (tmp_path / "x.ssp").write_text("not a zip")
    with pytest.raises(ConfigError, match="cannot open the SSP archive"):
        from bridge.plant.system.ssp import read_ssp

        read_ssp(tmp_path / "x.ssp")
    assert not zipfile.is_zipfile(tmp_path / "x.ssp")


def test_bad_connection_syntax_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"not of the form 'a\.y -> b\.u'"):
        experiment(tmp_path, ["motor.omega => load.omega_in"])
