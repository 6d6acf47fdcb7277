"""Python-backed FMUs (pythonfmu, pythonfmu3 exports) from the command line.

They run in a child process by default: an FMU whose embedded interpreter aborts at exit after a
correct run (tests/data/slaves/AbortAtExit2.py) leaves the command's exit status alone, and one
whose class import fails shows its own ``ModuleNotFoundError``. Packages missing from the FMU's
``resources/requirements.txt`` are named before anything is loaded.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bridge.experiment.config import load_experiment
from bridge.plant.factory import experiment_plant
from tests.conftest import DATA, _pythonfmu_build, unimportable_fmu

pytestmark = pytest.mark.integration


def cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "bridge.cli", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, timeout=600, check=False, cwd=cwd)


def experiment_for(fmu: Path) -> Path:
    path = fmu.parent / f"{fmu.stem}.yaml"
    run = cli("init", fmu, "-o", path, cwd=fmu.parent)
    assert run.returncode == 0, run.stdout + run.stderr
    return path


@pytest.fixture(scope="module")
def abort_at_exit(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("pythonfmu")
    out = tmp_path_factory.mktemp("abort")
    return experiment_for(_pythonfmu_build("pythonfmu", DATA / "slaves" / "AbortAtExit2.py", out))


def test_python_backed_fmu_runs_in_a_child_process_by_default(abort_at_exit: Path) -> None:
    plant = experiment_plant(load_experiment(abort_at_exit))
    try:
        assert plant.isolated
    finally:
        plant.close()


def test_an_abort_at_the_fmus_exit_does_not_decide_the_exit_status(abort_at_exit: Path) -> None:
    run = cli("simulate", abort_at_exit, "--episodes", "1", cwd=abort_at_exit.parent)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "steps: 1000" in run.stdout


@pytest.mark.parametrize("tool", ["pythonfmu", "pythonfmu3"])
def test_missing_requirements_are_named_before_the_run(tool: str, tmp_path: Path) -> None:
    fmu = unimportable_fmu(tool, tmp_path, requirements="fmu-bridge-absent-package>=1.0\nnumpy>=1\n")
    run = cli("check", experiment_for(fmu), cwd=tmp_path)
    said = run.stdout + run.stderr
    assert run.returncode != 0
    assert "fmu-bridge-absent-package>=1.0 (not installed)" in said
    assert "numpy" not in said.partition("needs packages")[2].partition("(from")[0]  # installed
    assert "-m pip install 'fmu-bridge-absent-package>=1.0'" in said
    assert "Traceback" not in said


def test_a_failed_class_import_shows_the_fmus_own_message(tmp_path: Path) -> None:
    fmu = unimportable_fmu("pythonfmu", tmp_path)
    run = cli("check", experiment_for(fmu), cwd=tmp_path)
    said = run.stdout + run.stderr
    assert run.returncode != 0
    assert "No module named 'fmu_bridge_absent_package'" in said
    assert "Traceback" not in said
