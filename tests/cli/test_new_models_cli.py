"""The FMI 3.0 array and clock models as a new user meets them: listed by ``models``, named as
``example:...`` in an experiment, and ``init`` writing what they need (structural parameters,
clocks, whether a state file is possible) as lines that ``check`` accepts once uncommented."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.errors import StateFileError
from bridge.models import example_fmu

runner = CliRunner()
_load_plugins()


def invoke(*args: str) -> str:
    result = runner.invoke(app, list(args), env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output + repr(result.exception)
    return result.output


def _uncomment(text: str, key: str) -> str:
    return text.replace(f"  # {key}:", f"  {key}:")


def test_models_lists_the_array_and_clock_models_and_experiments_name_them() -> None:
    rows = json.loads(invoke("models", "--json"))
    listed = {(r["model"], r["interface"]) for r in rows if r["model"] in ("strict_arrays", "clocks3")}
    assert listed == {
        ("strict_arrays", "cs"),
        ("strict_arrays", "me"),
        ("clocks3", "cs"),
        ("clocks3", "me"),
        ("clocks3", "se"),
    }
    assert all(Path(r["path"]).is_file() for r in rows)
    assert example_fmu("clocks3", "3.0", "se").name.startswith("clocks3-fmi3-se")


def test_init_on_the_strict_array_model_offers_its_structural_parameter(tmp_path: Path) -> None:
    target = tmp_path / "arrays.yaml"
    invoke("init", str(example_fmu("strict_arrays", "3.0", "cs")), "-o", str(target))
    text = target.read_text()
    assert '# structural_parameters: {"n": 3}' in text
    assert "{state_file: PATH}" not in text and "cannot save its state to a file" in text
    target.write_text(_uncomment(text, "structural_parameters"))
    data = yaml.safe_load(target.read_text())
    assert data["model"]["structural_parameters"] == {"n": 3}
    out = invoke("check", str(target), "--steps", "2")
    assert "stable-baselines3 env checker passed" in out


def test_init_on_the_clock_model_offers_its_settable_clocks(tmp_path: Path) -> None:
    target = tmp_path / "clocks.yaml"
    invoke("init", str(example_fmu("clocks3", "3.0", "se")), "-o", str(target))
    text = target.read_text()
    assert '# clock_intervals: {"c_fixed": 0.25}' in text
    assert '# clock_schedule: {"trigger": [1.0]}' in text
    target.write_text(_uncomment(_uncomment(text, "clock_intervals"), "clock_schedule"))
    data = yaml.safe_load(target.read_text())
    assert data["model"]["clock_schedule"] == {"trigger": [1.0]}
    out = invoke("check", str(target), "--steps", "5")
    assert "stable-baselines3 env checker passed" in out


def test_init_offers_a_state_file_where_the_fmu_can_save_one(tmp_path: Path) -> None:
    target = tmp_path / "slow.yaml"
    invoke("init", str(example_fmu("slow_init", "2.0", "cs")), "-o", str(target))
    assert "{state_file: PATH}" in target.read_text()


def test_state_save_refusal_for_scheduled_execution_reads_its_own_flags(tmp_path: Path) -> None:
    # clocks3's ScheduledExecution element declares canGetAndSetFMUState="true"; the refusal used to
    # read the (absent) ModelExchange element and report it false
    exp = tmp_path / "se.yaml"
    invoke("init", str(example_fmu("clocks3", "3.0", "se")), "-o", str(exp))
    result = runner.invoke(app, ["state", "save", str(exp), "--until", "1", "-o", str(tmp_path / "s")])
    assert isinstance(result.exception, StateFileError)
    message = str(result.exception)
    assert "canSerializeFMUState=false and canGetAndSetFMUState=true" in message
    assert not (tmp_path / "s").exists()


def test_check_refuses_a_clock_setting_before_saying_config_ok(tmp_path: Path) -> None:
    """Before: ``check`` printed "config ok" and then failed opening the FMU on the same setting."""
    target = tmp_path / "clocks.yaml"
    invoke("init", str(example_fmu("clocks3", "3.0", "cs")), "-o", str(target))
    data = yaml.safe_load(target.read_text())
    data["model"]["clock_intervals"] = {"c_calc": 0.3}  # calculated by the FMU: not the importer's
    target.write_text(yaml.safe_dump(data))
    result = runner.invoke(app, ["check", str(target)], env={"COLUMNS": "200"})
    assert result.exit_code != 0
    assert "config ok" not in result.output
    assert "the interval of clock 'c_calc' cannot be set" in str(result.exception)
    assert str(target) in str(result.exception)


def test_an_element_beyond_the_configured_size_names_the_array_and_its_size(tmp_path: Path) -> None:
    """Before: with ``n: 2``, ``u[3]`` was only "not a variable of the FMU", with no word of the size."""
    target = tmp_path / "arrays.yaml"
    invoke("init", str(example_fmu("strict_arrays", "3.0", "cs")), "-o", str(target))
    data = yaml.safe_load(target.read_text())
    data["model"]["structural_parameters"] = {"n": 2}  # the experiment still names u[1]..u[3]
    target.write_text(yaml.safe_dump(data))
    result = runner.invoke(app, ["check", str(target)], env={"COLUMNS": "200"})
    assert result.exit_code != 0
    message = str(result.exception)
    assert (
        "'u[3]' is not a variable of the FMU (u is Float64[2] here, sized by model.structural_parameters"
        in message
    )


def test_check_shows_many_signals_a_row_each_on_a_narrow_terminal(tmp_path: Path) -> None:
    """Before: clocks3's 20 observations got a column each on 80 columns, every name cut to '…',
    and the time column's header "t [s]" lost its unit to rich's markup."""
    target = tmp_path / "clocks.yaml"
    invoke("init", str(example_fmu("clocks3", "3.0", "cs")), "-o", str(target))
    result = runner.invoke(app, ["check", str(target), "--steps", "4"], env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert all(len(line) <= 80 for line in lines)
    (countdown,) = [line for line in lines if line.startswith("│ n_countdown")]  # a row, its name whole
    assert countdown.split("│")[2:6] == [
        " 2      ",
        " 3      ",
        " 4      ",
        " 4      ",
    ]  # 0.05, 0.15, 0.45, 0.75
    assert any("t [s]" in line for line in lines)


def test_inspect_says_which_structural_parameter_sizes_an_array() -> None:
    """Before: ``Float64[3]``, with nothing saying that ``n`` sets the 3."""
    path = str(example_fmu("strict_arrays", "3.0", "cs"))
    table = invoke("inspect", path)
    assert "type: Float64[n=3]" in table and "type: Float64[2,n=3]" in table
    variables = {v["name"]: v for v in json.loads(invoke("inspect", path, "--json"))["variables"]}
    assert variables["y"]["dimensions"] == [2, 3] and variables["y"]["sized_by"] == [None, "n"]
