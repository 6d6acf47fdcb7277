"""The command line, through typer's CliRunner and, for the main paths, as real subprocesses."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.experiment.examples import example_experiment

runner = CliRunner()
_load_plugins()
ENV = {**os.environ, "COLUMNS": "200"}


def invoke(*args: str) -> str:
    result = runner.invoke(app, list(args), env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output + repr(result.exception)
    return result.output


def test_inspect_json_lists_typed_variables(typed_fmu3: Path) -> None:
    info = json.loads(invoke("inspect", str(typed_fmu3), "--json"))
    assert info["fmi_version"] == "3.0" and info["interfaces"] == ["CS"]
    assert info["default_experiment"]["step_size_s"] is not None
    by_name = {v["name"]: v for v in info["variables"]}
    assert by_name["uint64_in"]["type"] == "UInt64"
    assert by_name["enum_in"]["enumeration"]
    assert by_name["double_gain"]["causality"] == "calculatedParameter"


def test_inspect_table_shows_units_bounds_and_platforms(cartpole_fmu: Path) -> None:
    out = invoke("inspect", str(cartpole_fmu))
    assert "FMI 2.0" in out and "linux64" in out
    assert "force" in out and "input" in out and "-10" in out and "N" in out


def test_inspect_a_broken_file_exits_2_with_a_clear_message(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.fmu"
    bogus.write_text("nope")
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "inspect", str(bogus)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=120,
        check=False,
    )
    assert result.returncode == 2
    assert "not an FMU: expected a zip archive" in result.stderr
    assert "Traceback" not in result.stderr


def test_models_lists_and_builds_every_variant() -> None:
    rows = json.loads(invoke("models", "--json"))
    models = {"cartpole", "dcmotor", "bouncing_ball", "stair", "typed", "typed3", "feedthrough"}
    models |= {"gearload", "pi_controller", "motor_gearload", "vehicle", "modelica_names", "global_state"}
    models |= {"slow_init", "slow_init_late", "strict_arrays", "clocks3", "slow_plant"}
    assert {r["model"] for r in rows} == models
    assert len(rows) == 50 and all(Path(r["path"]).is_file() for r in rows)
    assert "cartpole" in invoke("models")  # and the table for people


def test_init_writes_a_config_that_check_accepts(tmp_path: Path, cartpole_fmu: Path) -> None:
    target = tmp_path / "experiment.yaml"
    invoke("init", str(cartpole_fmu), "-o", str(target))
    text = target.read_text()
    data = yaml.safe_load(text)
    assert data["actions"]["inputs"] == ["force"]
    assert data["observations"]["outputs"] == ["x", "x_dot", "theta", "theta_dot"]
    assert '"m_pole": 0.1' in text  # parameters listed with their defaults
    out = invoke("check", str(target), "--steps", "3")
    assert "gymnasium env checker passed" in out and "stable-baselines3 env checker passed" in out
    refused = runner.invoke(app, ["init", str(cartpole_fmu), "-o", str(target)])
    assert refused.exit_code != 0 and "--force" in str(refused.exception)


def test_simulate_prints_one_row_per_episode_and_records(tmp_path: Path) -> None:
    out = invoke(
        "simulate",
        str(example_experiment("cartpole_balance")),
        "--episodes",
        "3",
        "--policy",
        "random",
        "--recordings",
        str(tmp_path),
    )
    recordings = list(tmp_path.glob("*.mcap"))
    assert len(recordings) == 1 and "recording:" in out
    rows = [line for line in out.splitlines() if "bounds:" in line or "time" in line]
    assert len(rows) >= 3


def test_simulate_constant_policy_on_a_named_scenario() -> None:
    out = invoke(
        "simulate",
        "--no-record",
        str(example_experiment("dcmotor_tracking")),
        "--scenario",
        "heavy_load",
        "--policy",
        "constant:12",
    )
    assert "heavy_load" in out and "300" in out


def test_simulate_rejects_an_unknown_policy() -> None:
    result = runner.invoke(
        app, ["simulate", str(example_experiment("cartpole_balance")), "--policy", "smart"]
    )
    assert result.exit_code != 0 and "zero, start, random or constant:VALUE" in str(result.exception)


def test_scenarios_shows_schedule_and_samples() -> None:
    out = invoke("scenarios", str(example_experiment("dcmotor_tracking")), "--sample", "3", "--seed", "1")
    assert "heavy_load" in out and "evaluation" in out and "3 sampled episodes" in out and "J=" in out


def test_quick_demo_balances_with_a_controller() -> None:
    out = invoke("demo", "--quick")
    assert "episode return 500.0 over 500 samples (time)" in out


@pytest.mark.slow
@pytest.mark.timeout(2400)  # 60k PPO steps: ~3 min on 2 idle cores, 10+ min at load average 10
def test_demo_trains_evaluates_and_reports_as_a_real_subprocess(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "demo"],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=2300,
        check=False,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    out = result.stdout
    ppo = next(line for line in out.splitlines() if line.startswith("│ ppo"))
    assert float(ppo.split("│")[2]) >= 475.0  # PPO's mean return over 20 episodes
    report = next(line.split()[-1] for line in out.splitlines() if line.startswith("report:"))
    assert (tmp_path / report).is_file()


SESSION_COMMANDS = (
    ["node"], ["nodes"], ["record"], ["replay"], ["agent", "run"], ["train"], ["system", "serve"]
)  # fmt: skip


@pytest.mark.parametrize("command", SESSION_COMMANDS, ids=" ".join)
def test_every_command_that_opens_a_zenoh_session_takes_the_zenoh_mode(command: list[str]) -> None:
    assert "--zenoh-mode" in " ".join(invoke(*command, "--help").split())


def test_a_bad_zenoh_mode_is_refused_before_a_session_opens(tmp_path: Path) -> None:
    for mode, extra, message in (
        ("router", [], "use client or peer"),
        ("client", ["--listen", "tcp/127.0.0.1:0"], "a client does not accept connections"),
    ):
        result = runner.invoke(
            app, ["record", "--node", "n", "-o", str(tmp_path / "r.mcap"), "--zenoh-mode", mode, *extra]
        )
        assert result.exit_code != 0 and message in str(result.exception)
