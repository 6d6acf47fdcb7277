"""An FMU that fails to load in the child process is reported as it is in this process.

FMUs that declare ``canBeInstantiatedOnlyOncePerProcess`` (and isolated plants) run in a child
process. The FMU here is pythonfmu's export of the heater with that flag, its Linux binary taken
out: loading it fails ("no binary for this platform") in the child, and ``check`` prints the
same one-paragraph message as in process: no traceback, no hint about standard input.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from bridge.errors import FmuLoadError
from bridge.experiment.config import load_experiment
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant
from tests.conftest import DATA, _pythonfmu_build

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def windows_only(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("pythonfmu")
    out = tmp_path_factory.mktemp("once")
    built = _pythonfmu_build(
        "pythonfmu", DATA / "slaves" / "Heater2.py", out / "built", flags=["--only-one-per-process"]
    )
    path = out / "Heater2.fmu"
    with zipfile.ZipFile(built) as source, zipfile.ZipFile(path, "w") as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/linux64/"):
                target.writestr(item, source.read(item))
    return path


@pytest.fixture(scope="module")
def experiment_file(windows_only: Path) -> Path:
    path = windows_only.parent / "heater.yaml"
    run = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "init", str(windows_only), "-o", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    return path


def test_child_load_error_is_the_in_process_error(experiment_file: Path) -> None:
    experiment = load_experiment(experiment_file)
    with pytest.raises(FmuLoadError) as in_process:
        LocalFmuPlant(experiment_plant_spec(experiment)).bind(["power"], ["room"])
    plant = IsolatedFmuPlant(experiment_plant_spec(experiment))
    try:
        with pytest.raises(FmuLoadError) as in_child:
            plant.bind(["power"], ["room"])
    finally:
        plant.close()
    assert str(in_child.value) == str(in_process.value)
    assert "no binary for this platform (linux64)" in str(in_child.value)


def test_check_prints_one_paragraph_and_no_traceback(experiment_file: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "check", str(experiment_file)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    said = run.stdout + run.stderr
    assert run.returncode != 0
    assert "no binary for this platform (linux64)" in said
    assert "Traceback" not in said
    assert "standard input" not in said
