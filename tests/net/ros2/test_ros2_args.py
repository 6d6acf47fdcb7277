"""--ros-args as launch_ros's Node appends them: taken out of the command line and applied."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bridge.errors import ConfigError
from bridge.net.ros2.args import split_ros_args


def test_ros_args_are_split_off_and_parsed(tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  ros__parameters:\n    per_variable: true\n    depth: 5\n")
    argv = [
        "node", "cp.yaml", "--ros",
        "--ros-args", "-r", "__node:=plant", "-r", "__ns:=/robot1", "-r", "outputs:=state",
        "--params-file", str(params), "-p", "domain_id:=7", "--",
        "--name", "cp",
    ]  # fmt: skip
    rest, ros = split_ros_args(argv)
    assert rest == ["node", "cp.yaml", "--ros", "--name", "cp"]
    assert (ros.namespace, ros.node_name, ros.remaps) == ("/robot1", "plant", {"outputs": "state"})
    assert ros.parameters == {"per_variable": True, "depth": 5, "domain_id": 7}
    section = ros.apply({"namespace": "/", "clock": False})
    assert section == {
        "namespace": "/robot1",
        "node_name": "plant",
        "clock": False,
        "per_variable": True,
        "depth": 5,
        "domain_id": 7,
        "outputs_topic": "state",
    }


def test_ros_args_that_we_cannot_honour_are_refused_clearly() -> None:
    with pytest.raises(ConfigError, match="must read FROM:=TO"):
        split_ros_args(["--ros-args", "-r", "nonsense"])
    with pytest.raises(ConfigError, match="'--disable-rosout-logs' is not supported"):
        split_ros_args(["--ros-args", "--disable-rosout-logs", "x"])
    split_ros_args([])


def test_the_command_line_accepts_what_launch_ros_appends() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "version", "--ros-args", "-r", "__node:=fmu", "-r", "__ns:=/a"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
