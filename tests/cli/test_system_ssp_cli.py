"""``fmu-bridge system inspect|check|simulate`` on an .ssp itself, and on components served elsewhere."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from tests.conftest import Loopback
from tests.plant.ssp_semantics import motor_load, write

runner = CliRunner()
_load_plugins()
NAMES = ["motor.omega", "motor.current", "load.omega", "load.torque"]
EXAMPLE_YAML = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"


def invoke(*args: str) -> str:
    result = runner.invoke(app, list(args), env={"COLUMNS": "200"})
    assert result.exit_code == 0, (result.output, result.exception)
    return result.output


def one_way_ssp(tmp_path: Path, name: str = "one_way.ssp", *, step: bool = True) -> Path:
    """The motor drives the load through a linear transformation; the load does not act back."""
    text = motor_load(omega='<ssc:LinearTransformation factor="0.5" offset="0.25"/>')
    text = text.replace(
        '<ssd:Connection startElement="load" startConnector="torque" endElement="motor" '
        'endConnector="load_torque"></ssd:Connection>',
        "",
    )
    assert 'load_torque"></ssd:Connection>' not in text
    return write(tmp_path / name, text if step else text.replace('<x stepSize="0.001"/>', ""))


def test_inspect_and_check_take_an_ssp(tmp_path: Path) -> None:
    ssp = one_way_ssp(tmp_path)
    data = json.loads(invoke("system", "inspect", str(ssp), "--json"))
    assert [c["name"] for c in data["components"]] == ["motor", "load"]
    assert data["connections"] == ["motor.omega -> load.omega_in"] and data["macro_step_s"] == 0.001
    assert "1 connections valid" in invoke("system", "check", str(ssp), "--steps", "3")


def test_simulate_an_ssp_matches_libcosim_reading_the_same_file(tmp_path: Path) -> None:
    from tests.plant.test_system_ssp_semantics import STEPS, libcosim

    ssp = one_way_ssp(tmp_path)
    out = tmp_path / "run.csv"
    invoke("system", "simulate", str(ssp), "--csv", str(out), "--every", "100")
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 401 and float(rows[-1]["time"]) == pytest.approx(0.4)  # its stopTime
    ours = np.array([[float(r[n]) for n in NAMES] for r in rows])
    reference = libcosim(ssp)
    np.testing.assert_allclose(ours[1 : STEPS + 1], reference, rtol=0, atol=1e-9)
    assert np.max(np.abs(ours[:, 2])) > 1.0


def test_an_ssp_without_a_step_size_asks_for_one(tmp_path: Path) -> None:
    ssp = one_way_ssp(tmp_path, "nostep.ssp", step=False)
    result = runner.invoke(app, ["system", "inspect", str(ssp)])
    assert (
        result.exit_code != 0 and "--step-size" in str(result.exception) and str(ssp) in str(result.exception)
    )
    assert "motor.omega" in invoke("system", "inspect", str(ssp), "--step-size", "0.002", "--json")


@pytest.mark.integration
def test_simulate_reaches_a_component_served_elsewhere_with_connect(
    tmp_path: Path, loopback: Loopback
) -> None:
    """The load in a `system serve` process; `system simulate --connect` drives it: the same CSV."""
    from tests.plant.test_system_nodes import EXAMPLE, serve, system_file

    local, remote = tmp_path / "local.csv", tmp_path / "remote.csv"
    args = ["--duration", "0.2", "--input", "controller.reference=20", "--every", "100"]
    invoke("system", "simulate", str(EXAMPLE), "--csv", str(local), *args)
    served = system_file(tmp_path, "served", {"load": "load-node"})
    assert yaml.safe_load(served.read_text())["system"]["components"]["load"]["node"] == "load-node"
    with serve(served, loopback, "load"):
        net = ["--connect", loopback.endpoint, "--prefix", loopback.prefix]
        invoke("system", "simulate", str(served), "--csv", str(remote), *args, *net)
    assert remote.read_text() == local.read_text()
    assert len(local.read_text().splitlines()) == 22


def test_a_coupled_ssp_runs_from_the_cli_with_its_loop_opened(tmp_path: Path) -> None:
    """Both directions coupled: the FMUs declare no output dependencies, so it is an algebraic
    loop until --no-feedthrough says the motor has none; then libcosim's trajectory."""
    from tests.plant.test_system_ssp_semantics import LINEAR_TORQUE, STEPS, libcosim

    ssp = write(tmp_path / "coupled.ssp", motor_load(torque=LINEAR_TORQUE))
    refused = runner.invoke(app, ["system", "simulate", str(ssp)])
    assert refused.exit_code != 0 and "algebraic loop" in str(refused.exception)
    out = tmp_path / "run.csv"
    invoke("system", "simulate", str(ssp), "--no-feedthrough", "motor", "--csv", str(out), "--every", "100")
    rows = list(csv.DictReader(out.open()))
    ours = np.array([[float(r[n]) for n in NAMES] for r in rows])
    np.testing.assert_allclose(ours[1 : STEPS + 1], libcosim(ssp), rtol=0, atol=1e-9)
    misuse = runner.invoke(app, ["system", "check", str(EXAMPLE_YAML), "--no-feedthrough", "motor"])
    assert misuse.exit_code != 0 and "apply to .ssp/.ssd/OSP files" in str(misuse.exception)
