"""An FMU that will not start says why: the FMU's own words reach the error; archives as other
tools write them are read.

The FMU is a Python-backed export (pythonfmu, FMI 2.0) whose class import fails when it runs: it
logs the ``ModuleNotFoundError`` only to a logger that was asked to log, so an instance created
with logging off is just NULL. (pythonfmu3's FMI 3.0 twin crashes its process in the same case: it
is run in a child process, tests/plant/test_python_backed.py.)
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.errors import FmuError, FmuLoadError
from bridge.fmu import Model, read_model_info
from tests.conftest import example_fmu, unimportable_fmu


@pytest.fixture(scope="module")
def unimportable(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return unimportable_fmu("pythonfmu", tmp_path_factory.mktemp("pythonfmu"))


def test_null_instance_error_carries_the_fmus_own_message(unimportable: Path) -> None:
    with Model(unimportable, step_size_s=0.1) as model, pytest.raises(FmuError) as caught:
        model.initialize()
    message = str(caught.value)
    assert "Instantiate returned NULL" in message
    assert "No module named 'fmu_bridge_absent_package'" in message
    assert any("fmu_bridge_absent_package" in line for line in caught.value.log)


def test_an_archive_with_backslash_paths_lists_its_platforms(tmp_path: Path) -> None:
    fmu = tmp_path / "windows_zip.fmu"
    with zipfile.ZipFile(example_fmu("dcmotor", "2.0", "cs")) as source, zipfile.ZipFile(fmu, "w") as out:
        for item in source.infolist():
            out.writestr(item.filename.replace("/", "\\"), source.read(item))
    info = read_model_info(fmu)
    assert "linux64" in info.platforms and "c-code" in info.platforms
    assert any("backslashes" in problem for problem in info.problems)  # why it is not run as is
    shown = CliRunner().invoke(app, ["inspect", str(fmu)])
    assert shown.exit_code == 0 and "source only" not in shown.output
    assert "linux64" in shown.output


def test_missing_requirements_are_named_before_anything_loads(tmp_path: Path) -> None:
    fmu = unimportable_fmu("pythonfmu", tmp_path, requirements="fmu-bridge-absent-package>=1.0\n")
    info = read_model_info(fmu)
    assert info.python_backed and info.needs_execution_tool
    with pytest.raises(FmuLoadError, match=r"fmu-bridge-absent-package>=1.0 \(not installed\)"):
        Model(fmu, step_size_s=0.1)
