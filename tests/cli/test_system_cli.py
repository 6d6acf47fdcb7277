"""``fmu-bridge system ...`` and training on a system, through the real command line."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app

runner = CliRunner()
_load_plugins()
EXAMPLES = Path(__file__).parents[2] / "examples"
SYSTEM = EXAMPLES / "dcmotor_system.yaml"


def invoke(*args: str) -> str:
    result = runner.invoke(app, list(args), env={"COLUMNS": "200"})
    assert result.exit_code == 0, (result.output, result.exception)
    return result.output


def test_inspect_lists_components_connections_and_draws_the_graph(tmp_path: Path) -> None:
    data = json.loads(invoke("system", "inspect", str(SYSTEM), "--json"))
    assert [c["name"] for c in data["components"]] == ["controller", "motor", "load"]
    assert "load.torque -> motor.load_torque" in data["connections"]
    assert {c["name"]: c["step_size_s"] for c in data["components"]}["motor"] == 0.0005
    out = invoke(
        "system", "inspect", str(SYSTEM), "--dot", str(tmp_path / "g.dot"), "--png", str(tmp_path / "g.png")
    )
    assert "controller.u -> motor.voltage" in out
    dot = (tmp_path / "g.dot").read_text()
    assert '"load" -> "motor" [label="torque -> load_torque"]' in dot
    assert (tmp_path / "g.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_check_runs_a_few_samples() -> None:
    assert "4 connections valid" in invoke("system", "check", str(SYSTEM), "--steps", "3")


def test_simulate_writes_the_trajectory(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    invoke(
        "system",
        "simulate",
        str(SYSTEM),
        "--duration",
        "1",
        "--input",
        "controller.reference=20",
        "--csv",
        str(out),
    )
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 101 and float(rows[-1]["time"]) == pytest.approx(1.0)
    # the PI controller brings the load near its set-point within a second
    assert abs(float(rows[-1]["load.omega"]) - 20.0) < 2.0


def test_bad_system_is_a_clean_error(tmp_path: Path) -> None:
    text = SYSTEM.read_text().replace(
        "load.omega -> controller.measurement", "load.omegax -> controller.measurement"
    )
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    result = runner.invoke(app, ["system", "check", str(bad)])
    assert result.exit_code != 0
    assert "omegax" in str(result.exception) and "bad.yaml" in str(result.exception)


@pytest.mark.slow
def test_an_agent_trains_on_one_input_of_a_system(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    from agents.train import train

    result = train(
        EXAMPLES / "dcmotor_system_tracking.yaml",
        overrides={"timesteps": 2048},
        run_dir=tmp_path / "run",
        progress=False,
    )
    assert result.timesteps >= 2048 and result.model_path.exists()


def test_serve_refuses_a_system_without_node_components() -> None:
    result = runner.invoke(app, ["system", "serve", str(SYSTEM)], env={"COLUMNS": "200"})
    assert result.exit_code != 0
    message = str(result.exception)
    assert "no component of the system has node:" in message and str(SYSTEM) in message
