"""FMI 3.0 arrays (element-wise as ``y[2,3]``, 1-based, row-major), Binary and clocks.

Arrays run on an FMU exported by pythonfmu3; clocks and scheduled execution are read from a
model description (``inspect`` needs no binary); tests/fmu/test_clocks.py runs them.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.errors import FmuLoadError, VariableError
from bridge.fmu import Model, read_model_info
from bridge.fmu.vocab import info_from_summary, summary_of

SLAVES = Path(__file__).resolve().parent.parent / "data" / "slaves"


@pytest.fixture(scope="module")
def arrays3(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pythonfmu3's export of tests/data/slaves/Arrays3.py (u[3], k[3] in; y[2,3], n[3] out)."""
    pytest.importorskip("pythonfmu3")
    out = tmp_path_factory.mktemp("arrays3")
    cmd = [sys.executable, "-m", "pythonfmu3", "build", "-f", str(SLAVES / "Arrays3.py"), "-d", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    if result.returncode != 0:
        pytest.fail(f"pythonfmu3 could not export Arrays3.py:\n{result.stdout}\n{result.stderr}")
    return out / "Arrays3.fmu"


def test_arrays_have_dimensions_and_element_names(arrays3: Path) -> None:
    info = read_model_info(arrays3)
    assert info.variables["y"].dimensions == (2, 3) and info.variables["u"].dimensions == (3,)
    assert info.variables["y"].element_names() == ["y[1,1]", "y[1,2]", "y[1,3]", "y[2,1]", "y[2,2]", "y[2,3]"]
    assert "y[2,3]" in info.scalar_names() and "y" not in info.scalar_names()
    assert info.element("y[2,1]") == (info.variables["y"], 3)  # row-major: (2-1) * 3 + (1-1)
    with pytest.raises(VariableError, match=r"'y\[3,1\]': index out of range for array y\[2,3\].*1-based"):
        info.element("y[3,1]")
    with pytest.raises(VariableError, match=r"'u\[0\]'.*1-based"):
        info.element("u[0]")
    again = info_from_summary(json.loads(json.dumps(summary_of(info))))
    assert again.variables["y"].dimensions == (2, 3) and again.scalar_names() == info.scalar_names()


def test_inspect_shows_array_dimensions_in_the_table_and_json(arrays3: Path) -> None:
    table = CliRunner().invoke(app, ["inspect", str(arrays3)], env={"COLUMNS": "200"})
    assert table.exit_code == 0, table.output
    assert "Float64[2,3]" in table.output and "Int64[3]" in table.output
    as_json = CliRunner().invoke(app, ["inspect", str(arrays3), "--json"])
    variables = {v["name"]: v for v in json.loads(as_json.output)["variables"]}
    assert variables["y"]["dimensions"] == [2, 3] and "dimensions" not in variables["time"]


def test_array_elements_are_read_and_written_by_name(arrays3: Path) -> None:
    with Model(arrays3, step_size_s=0.5) as model:
        model.initialize()
        model.set({"u": [1.0, 2.0, 3.0], "k[2]": 2**63 - 2})
        model.set({"u[3]": 4.0})  # one element: the others keep their values
        assert model.get(["u", "k[2]", "k[1]"]) == {
            "u": pytest.approx([1.0, 2.0, 4.0]),
            "k[2]": 2**63 - 2,
            "k[1]": 0,
        }
        model.advance(1)
        values = model.get(["y", "n", "y[2,3]"])
        np.testing.assert_array_equal(values["y"], [[1.0, 2.0, 4.0], [10.5, 20.5, 40.5]])
        assert values["n"].tolist() == [1, 2**63 - 1, 1] and values["y[2,3]"] == 40.5
        with pytest.raises(VariableError, match=r"'u' is an array of shape \(3,\) \(3 elements\), got 2"):
            model.set({"u": [1.0, 2.0]})


def test_signal_groups_flatten_array_elements(arrays3: Path) -> None:
    with Model(arrays3, step_size_s=0.5) as model:
        model.initialize()
        actions = model.signals(["u[1]", "u[3]", "k[2]"], writable=True)
        observations = model.signals(["y[2,3]", "y[1,1]", "n[2]", "y[2,1]"])
        for step in range(1, 4):
            actions.write([float(step), -1.0, step])
            model.advance(1)
            t = 0.5 * step
            expected = [10.0 * -1.0 + t, float(step), step + 1, 10.0 * step + t]
            np.testing.assert_array_equal(observations.read(), expected)
        assert model.get(["u[2]"]) == {"u[2]": 0.0}  # never written: kept by the whole-array write
        with pytest.raises(VariableError, match=r"k\[2\]=9223372036854775808 \(Int64"):
            actions.write([0.0, 0.0, 2**63])


SCHEDULED = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="sched"
  instantiationToken="{00000000-0000-0000-0000-000000000001}">
  <ScheduledExecution modelIdentifier="sched"/>
  <ModelVariables>
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <Clock name="tick" valueReference="1" causality="input" intervalVariability="constant"
           intervalDecimal="0.01" shiftDecimal="0.002"/>
    <Clock name="trigger" valueReference="2" causality="input" intervalVariability="triggered"/>
    <Float64 name="y" valueReference="3" causality="output" variability="discrete" clocks="1"
             initial="exact" start="0"/>
    <Binary name="blob" valueReference="4" causality="output" variability="discrete" clocks="1"
            initial="exact">
      <Start value="0a0b"/>
    </Binary>
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="3"/>
    <Output valueReference="4"/>
  </ModelStructure>
</fmiModelDescription>
"""


@pytest.fixture
def scheduled_fmu(tmp_path: Path) -> Path:
    path = tmp_path / "sched.fmu"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", SCHEDULED)
    return path


def test_inspect_lists_clocks_with_kinds_and_intervals(scheduled_fmu: Path) -> None:
    info = read_model_info(scheduled_fmu)
    assert [v.name for v in info.clocks] == ["tick", "trigger"]
    assert info.variables["tick"].clock is not None and info.variables["tick"].clock.interval_s == 0.01
    assert info.variables["blob"].type == "Binary"
    result = CliRunner().invoke(app, ["inspect", str(scheduled_fmu)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "clock tick (input): constant, interval 0.01 s, shift 0.002 s" in result.output
    assert "clock trigger (input): triggered" in result.output
    assert "SE (scheduled execution)" in result.output
    data = json.loads(CliRunner().invoke(app, ["inspect", str(scheduled_fmu), "--json"]).output)
    assert data["clocks"] == ["tick", "trigger"] and data["scheduled_execution"] is True


def test_scheduled_execution_only_fmu_is_run_as_such(scheduled_fmu: Path) -> None:
    """Chosen as interface 'se' (this archive ships no binary, so loading it stops there)."""
    assert read_model_info(scheduled_fmu).interfaces == ("se",)
    with pytest.raises(FmuLoadError, match=r"sched.fmu has no binary for this platform"):
        Model(scheduled_fmu, step_size_s=0.01)
