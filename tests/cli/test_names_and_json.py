"""Small but visible: generated run and recording names are plain file names, ``compare`` and
``scenarios`` speak JSON and never cut names when piped, and the text the project prints or
documents names commands and modules that exist."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.util import find_spec
from pathlib import Path

import pytest
import yaml

from agents.settings import TrainingSettings
from agents.train import prepare_run_dir, train
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.init import starting_config
from bridge.models import example_fmu
from bridge.recording.env_recorder import record_env, slug

ROOT = Path(__file__).resolve().parents[2]
CARTPOLE = example_experiment("cartpole_balance")
MOTOR = example_experiment("dcmotor_tracking")


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bridge.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300,
        check=False, env={**os.environ, "COLUMNS": "80"},
    )  # fmt: skip


def test_slug_makes_plain_file_names() -> None:
    assert slug("ball tty") == "ball-tty"
    assert slug("policy:constant:2.5__nominal") == "policy-constant-2.5__nominal"
    assert slug("a / b") == "a-b" and slug("  ") == "run"
    # the demo's two constant baselines: a sign is not a separator
    assert slug("constant:-10__nominal") == "constant--10__nominal" != slug("constant:10__nominal")


def test_generated_run_and_recording_names_have_no_spaces(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = yaml.safe_load(CARTPOLE.read_text())
    data["name"] = "ball_tty.test"  # a name with spaces is refused by validation (tests/experiment)
    path = tmp_path / "spaced.yaml"
    path.write_text(yaml.safe_dump(data))
    experiment = load_experiment(path)
    monkeypatch.chdir(tmp_path)
    run = prepare_run_dir(TrainingSettings.from_experiment(experiment, {}), experiment, path, None)
    assert re.fullmatch(r"ball_tty\.test-v0-ppo-\d{8}-\d{6}", run.name), run.name
    with record_env(FmuEnv(experiment), tmp_path / "rec", agent="x") as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())
    (recording,) = (tmp_path / "rec").iterdir()
    assert recording.name.startswith("ball_tty.test-") and " " not in recording.name
    with record_env(FmuEnv(experiment), tmp_path / "rec2", run_name="constant:10__nominal") as env:
        env.reset(seed=0)
    assert [p.name for p in (tmp_path / "rec2").iterdir()] == ["constant-10__nominal.mcap"]


def test_scenarios_json_and_full_names_when_piped(tmp_path: Path) -> None:
    data = yaml.safe_load(MOTOR.read_text())
    long_name = "a_scenario_with_a_name_far_longer_than_eighty_columns_" + "x" * 40
    data["scenarios"][long_name] = data["scenarios"].pop("step_up")
    for key in ("training", "evaluation"):
        data["schedule"][key] = [long_name if s == "step_up" else s for s in data["schedule"].get(key, [])]
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(data))
    table = _cli("scenarios", str(path), "--sample", "3", cwd=tmp_path)
    assert table.returncode == 0, table.stderr
    assert long_name in table.stdout  # piped: one block per row, nothing cut
    result = _cli("scenarios", str(path), "--sample", "3", "--json", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    parsed = json.loads(result.stdout)
    assert long_name in [s["scenario"] for s in parsed["scenarios"]] and len(parsed["episodes"]) == 3
    assert all(set(e) == {"episode", "scenario", "drawn", "references"} for e in parsed["episodes"])


def test_compare_json_and_full_names_when_piped(tmp_path: Path) -> None:
    run = tmp_path / ("a_run_folder_with_a_name_far_longer_than_eighty_columns_" + "y" * 40)
    overrides = {
        "timesteps": 64,
        "n_envs": 1,
        "eval_every": 100_000,
        "hyperparams": {"n_steps": 64, "batch_size": 64},
    }
    train(CARTPOLE, overrides=overrides, run_dir=run, progress=False)
    table = _cli("compare", str(run), cwd=tmp_path)
    assert table.returncode == 0, table.stderr
    assert run.name in table.stdout
    result = _cli("compare", str(run), "--json", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    (row,) = json.loads(result.stdout)
    assert row["run"] == run.name and row["timesteps"] == 64 and row["status"] == "done"
    assert row["best_eval"] is None  # no evaluation yet: null, not NaN


def test_the_commands_init_suggests_for_an_observation_only_experiment_run(tmp_path: Path) -> None:
    text = starting_config(example_fmu("bouncing_ball", "2.0", "cs"))
    assert "evaluate --policy" not in text
    path = tmp_path / "ball.yaml"
    path.write_text(text)
    assert "`evaluate zero --config <this file>`" in text
    result = _cli("evaluate", "zero", "--config", str(path), "--episodes", "1", "--no-record",
                  "--out", str(tmp_path / "out"), cwd=tmp_path)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]


def test_every_module_the_readme_and_the_docs_name_exists() -> None:
    readme = "\n".join(p.read_text() for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
    names = set(re.findall(r"`((?:bridge|agents)(?:\.[a-z_0-9]+)+)`", readme))
    assert names, "the README and the docs name modules"
    missing = []
    for name in sorted(names):
        parts = name.split(".")
        # `bridge.env.fmu_env.FmuEnv`-style attributes: the longest importable prefix must hold the rest
        for cut in range(len(parts), 0, -1):
            try:
                if find_spec(".".join(parts[:cut])) is not None:
                    break
            except ModuleNotFoundError:  # a prefix that is a module, not a package
                continue
        else:
            missing.append(name)
            continue
        try:
            module = __import__(".".join(parts[:cut]), fromlist=["_"])
        except ModuleNotFoundError as exc:  # it exists; an optional stack (Ray, rclpy) is not installed
            if (exc.name or "").split(".")[0] in ("bridge", "agents"):
                raise
            continue
        obj = module
        for attr in parts[cut:]:
            obj = getattr(obj, attr, None)
            if obj is None:
                missing.append(name)
                break
    assert missing == [], f"the README or the docs name modules that do not exist: {missing}"
    assert "evaluate --policy" not in readme
