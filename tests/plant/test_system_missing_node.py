"""A system whose component node does not answer: the error says how to serve it (``system serve``)
and, for two ``--connect`` endpoints without ``--zenoh-mode peer``, that the client reaches one."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.errors import TransportError
from tests.conftest import router_on_loopback

pytestmark = pytest.mark.integration
runner = CliRunner()
_load_plugins()
EXAMPLE = Path(__file__).parents[2] / "examples" / "dcmotor_system.yaml"


def test_a_missing_component_node_names_system_serve_and_the_zenoh_mode(tmp_path: Path) -> None:
    data = yaml.safe_load(EXAMPLE.read_text())
    data["system"]["components"]["load"]["node"] = "far-load"
    path = tmp_path / "system.yaml"
    path.write_text(yaml.safe_dump(data))
    with router_on_loopback() as a, router_on_loopback() as b:
        args = ["system", "inspect", str(path), "--connect", a.endpoint, "--connect", b.endpoint]
        result = runner.invoke(app, [*args, "--prefix", a.prefix])
    assert isinstance(result.exception, TransportError), result.output
    message = str(result.exception)
    assert "system component 'load': no node 'far-load' answers" in message
    assert "`fmu-bridge system serve EXPERIMENT --component load`" in message
    assert "Zenoh client mode" in message and "add --zenoh-mode peer" in message
    assert a.endpoint in message and b.endpoint in message
