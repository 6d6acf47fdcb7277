"""Hostile names, numbers, keys and callables in experiment files.

Each once went through: a name that is a path wrote recordings outside ``--recordings``, a 5,000-digit
integer and ``uniform: [-1e308, 1e308]`` were tracebacks, a key given twice was silently merged and
``os:system`` was accepted as a reward. Each is now a ConfigError naming the key and the file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.safe import ALLOW_ENV
from bridge.recording.env_recorder import record_env
from bridge.task.core import load_callable

MOTOR = example_experiment("dcmotor_tracking")
runner = CliRunner()


def edited(tmp_path: Path, old: str, new: str) -> Path:
    text = MOTOR.read_text()
    assert old in text, old
    path = tmp_path / "experiment.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


def files_under(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")}


HOSTILE_NAMES = ["/tmp/x", "../../../../x", "n" * 10_000, "two\nlines", "gpj.\u202eexe", "", ".."]


@pytest.mark.parametrize(
    "name", HOSTILE_NAMES, ids=["absolute", "dotdot", "long", "newline", "rlo", "empty", "up"]
)
def test_a_hostile_experiment_name_is_a_config_error_and_writes_nothing(tmp_path: Path, name: str) -> None:
    work = tmp_path / "a" / "b" / "c" / "d" / "work"
    work.mkdir(parents=True)
    if name == "/tmp/x":
        name = str(tmp_path / "outside" / "x")  # an absolute path, kept inside this test's folder
    path = edited(work, "name: dcmotor-speed-tracking", f"name: {json.dumps(name)}")  # JSON strings are YAML
    before = files_under(tmp_path)
    result = runner.invoke(
        app,
        ["simulate", str(path), "--episodes", "1", "--recordings", str(work / "rec")],
        env={"COLUMNS": "200"},
    )
    assert isinstance(result.exception, ConfigError), result.output + repr(result.exception)
    message = str(result.exception)  # the console entry point prints it and exits with code 2
    assert "  name: " in message and "letters, digits" in message and str(path) in message, message
    assert files_under(tmp_path) == before


def test_a_hostile_run_name_writes_nothing_outside_the_recordings_folder(tmp_path: Path) -> None:
    folder = tmp_path / "deep" / "rec"
    folder.mkdir(parents=True)
    with FmuEnv(MOTOR) as env:
        for name in ["../../escaped", str(tmp_path / "abs"), "x" * 10_000, "a\nb", "a\u202eb", ".."]:
            with pytest.raises(ConfigError, match="give a plain file name") as caught:
                record_env(env, folder, run_name=name)
            assert str(folder) in str(caught.value)
        recorder = record_env(env, folder, run_name="ppo__step_up")
        recorder.reset(seed=0)
        recorder.close()
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == ["ppo__step_up.mcap"]


def test_plain_names_with_dots_and_dashes_are_accepted(tmp_path: Path) -> None:
    path = edited(tmp_path, "name: dcmotor-speed-tracking", "name: motor_v2.1-test")
    assert load_experiment(path).name == "motor_v2.1-test"


def test_a_5000_digit_integer_is_a_config_error_naming_the_line(tmp_path: Path) -> None:
    path = edited(tmp_path, "  seed: 0", "  seed: " + "7" * 5000)
    with pytest.raises(ConfigError, match=r"line \d+: an integer of 5000 digits; at most 30") as caught:
        load_experiment(path)
    assert str(path) in str(caught.value)


@pytest.mark.parametrize("values", ["[-1e308, 1e308]", "[0.0, 1e300]"])
def test_a_distribution_too_wide_to_draw_is_a_config_error(tmp_path: Path, values: str) -> None:
    path = edited(tmp_path, "J: {uniform: [0.008, 0.012]}", f"J: {{uniform: {values}}}")
    with pytest.raises(ConfigError, match=r"randomization\.parameters\.J: uniform: .* beyond \+-1e\+100"):
        load_experiment(path)


def test_a_key_given_twice_is_refused_not_merged(tmp_path: Path) -> None:
    path = edited(tmp_path, "  n_envs: 1\n", "  n_envs: 1\n  n_envs: 4\n")
    with pytest.raises(
        ConfigError, match=r"line \d+: key 'n_envs' is given twice in one mapping \(first at line"
    ):
        load_experiment(path)
    merged = edited(
        tmp_path,
        "  n_envs: 1\n",
        "  n_envs: 1\n  remote: {<<: {nodes: 'm-*', timeout_s: 2.0}, nodes: 'n-*'}\n",
    )
    remote = load_experiment(merged).training.remote
    assert (remote.nodes, remote.timeout_s) == ("n-*", 2.0)  # a merge key may still be overridden


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("reward:\n  terms:", "reward:\n  callable: os:system\n  terms:", "reward.callable"),
        ("schedule:", "hooks:\n  episode: os:system\nschedule:", "hooks.episode"),
        ("schedule:", "hooks:\n  state: subprocess:run\nschedule:", "hooks.state"),
        ("schedule:", "hooks:\n  state: numpy:save\nschedule:", "hooks.state"),
    ],
)
def test_callables_outside_the_users_modules_are_refused(
    tmp_path: Path, old: str, new: str, key: str
) -> None:
    path = edited(tmp_path, old, new)
    with pytest.raises(ConfigError) as caught:
        load_experiment(path)
    message = str(caught.value)
    assert f"{key}: " in message and "not a module of your own" in message, message
    assert ALLOW_ENV in message and str(path) in message


def test_an_explicit_list_allows_a_module_and_the_users_own_modules_pass(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ConfigError, match="not a module of your own"):
        load_callable("os.path:basename", "reward.callable")
    monkeypatch.setenv(ALLOW_ENV, "numpy, os")
    assert load_callable("os.path:basename", "reward.callable")("/a/b") == "b"
    assert load_experiment(edited(tmp_path, "schedule:", "hooks:\n  state: numpy:save\nschedule:"))
    monkeypatch.delenv(ALLOW_ENV)
    assert load_callable("rewards_for_tests:half_current", "reward.callable")({"current": 4.0}) == 2.0


def test_fmu_bridge_simulate_reports_a_refused_callable_as_exit_code_2(tmp_path: Path) -> None:
    path = edited(tmp_path, "reward:\n  terms:", "reward:\n  callable: os:system\n  terms:")
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "simulate", str(path), "--recordings", str(tmp_path / "rec")],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        timeout=300,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    assert "not a module of your own" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("__main__:main", "the program that is running"),
        ("bridge.cli:main", "part of fmu-bridge itself"),
        ("agents.train:train", "part of fmu-bridge itself"),
        (".rewards:reward", "not a module name"),
        ("..x:y", "not a module name"),
        ("rewards\x00:reward", "not a module name"),
        ("rewards_for_tests:half\x00", "not a function name"),
    ],
)
def test_main_the_projects_own_packages_relative_names_and_nul_bytes_are_config_errors(
    tmp_path: Path, spec: str, says: str
) -> None:
    """These passed the allow-list (``__main__``, fmu-bridge's packages) or raised a traceback
    (relative names, a NUL byte); each is now a ConfigError naming the key."""
    quoted = json.dumps(spec)  # YAML reads JSON's escapes
    path = edited(tmp_path, "reward:\n  terms:", f"reward:\n  callable: {quoted}\n  terms:")
    with pytest.raises(ConfigError, match=says) as caught:
        load_experiment(path)
    assert "reward.callable" in str(caught.value)
    if ":" in spec and "\x00" not in spec.partition(":")[2]:
        with pytest.raises(ConfigError, match=says):
            load_callable(spec, "reward.callable")
