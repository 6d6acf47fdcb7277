"""``system inspect``, ``check`` and ``simulate`` run a system's plant, which checks no task:
each command checks the experiment's task against the system's variables itself, once."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.errors import ConfigError

runner = CliRunner()
_load_plugins()
EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"


@pytest.mark.parametrize("command", ["inspect", "check", "simulate"])
def test_a_system_command_names_an_observation_no_component_has(command: str, tmp_path: Path) -> None:
    data = yaml.safe_load(EXAMPLE.read_text())
    data["observations"]["outputs"].append("motor.omegaa")
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(data))
    result = runner.invoke(app, ["system", command, str(path)])
    assert result.exit_code != 0
    assert isinstance(result.exception, ConfigError), result.output
    message = str(result.exception)
    assert "observations.outputs: 'motor.omegaa' is not a variable" in message and "motor.omega" in message
