"""An FMU that will not start says why: the FMU's own words reach the error.

The FMU is a Python-backed export (pythonfmu, FMI 2.0) whose class import fails when it runs: it
logs the ``ModuleNotFoundError`` only to a logger that was asked to log, so an instance created
with logging off is just NULL. (pythonfmu3's FMI 3.0 twin crashes its process in the same case: it
is run in a child process, tests/plant/test_python_backed.py.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.errors import FmuError
from bridge.fmu import Model
from tests.conftest import unimportable_fmu


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
