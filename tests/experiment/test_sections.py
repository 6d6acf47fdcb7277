"""The training, evaluation, recording, node and ros sections: typed, with "did you mean" errors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from agents.evaluate import baseline_settings, metric_spec
from agents.policies import PidSpec
from agents.settings import TrainingSettings
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.sections import PID_KEYS, RosSection
from bridge.net.ros2.view import RosViewSettings, settings_from
from tests.conftest import check_with_model

MOTOR = example_experiment("dcmotor_tracking")
CARTPOLE = example_experiment("cartpole_balance")


def with_changes(tmp_path: Path, source: Path, **sections: dict[str, Any]) -> Path:
    """``source`` with each section's keys merged in (one level deep), written to tmp_path."""
    data = yaml.safe_load(source.read_text())
    for name, changes in sections.items():
        data[name] = {**data.get(name, {}), **changes}
    path = tmp_path / source.name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.parametrize(
    ("section", "changes", "line"),
    [
        ("training", {"timestep": 10}, "training.timestep: unknown key; did you mean 'timesteps'?"),
        ("evaluation", {"metricz": {}}, "evaluation.metricz: unknown key; did you mean 'metrics'?"),
        (
            "recording",
            {"compresion": "zstd"},
            "recording.compresion: unknown key; did you mean 'compression'?",
        ),
        ("node", {"rat": 2.0}, "node.rat: unknown key; did you mean 'rate'?"),
        ("ros", {"domainid": 3}, "ros.domainid: unknown key; did you mean 'domain_id'?"),
    ],
)
def test_a_misspelt_key_names_the_key_the_file_and_close_matches(
    tmp_path: Path, section: str, changes: dict[str, Any], line: str
) -> None:
    path = with_changes(tmp_path, MOTOR, **{section: changes})
    with pytest.raises(ConfigError) as caught:
        load_experiment(path)
    message = str(caught.value)
    assert line in message and str(path) in message
    assert "Extra inputs are not permitted" not in message


def test_a_misspelt_success_metric_no_longer_disappears(tmp_path: Path) -> None:
    data = yaml.safe_load(MOTOR.read_text())
    data["evaluation"]["metrics"]["succes"] = data["evaluation"]["metrics"].pop("success")
    path = tmp_path / "motor.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(
        ConfigError, match=r"evaluation\.metrics\.succes: unknown key; did you mean 'success'\?"
    ):
        load_experiment(path)


def test_an_unknown_key_far_from_any_lists_what_the_section_takes(tmp_path: Path) -> None:
    path = with_changes(tmp_path, MOTOR, recording={"zzz": 1})
    with pytest.raises(ConfigError, match=r"recording\.zzz: unknown key; keys here: directory, compression"):
        load_experiment(path)


def test_an_unknown_top_level_section_gets_suggestions(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(CARTPOLE.read_text().replace("training:", "trainig:"))
    with pytest.raises(ConfigError, match=r"trainig: unknown key; did you mean 'training'\?"):
        load_experiment(path)


def test_check_on_the_command_line_exits_2_with_the_suggestion(tmp_path: Path) -> None:
    path = with_changes(tmp_path, CARTPOLE, training={"timestep": 10})
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "check", str(path)],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        timeout=300,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    assert "did you mean 'timesteps'?" in result.stderr and "Traceback" not in result.stderr


def test_the_examples_sections_are_read_as_typed_values() -> None:
    motor = load_experiment(MOTOR)
    assert motor.training.algo == "SAC" and motor.training.hyperparams["policy_kwargs"] == {
        "net_arch": [64, 64]
    }
    assert motor.evaluation.baselines["pid"].limits == (-24.0, 24.0)
    spec = metric_spec(motor)
    assert spec.tracking == [("omega", "omega_ref")] and spec.effort == ["voltage"]
    assert spec.constraints == {"current": (-30.0, 30.0)}
    assert spec.success == "abs(omega_steady_state_error) < 2.0"
    cartpole = load_experiment(CARTPOLE)
    assert metric_spec(cartpole).effort == ["force"]  # not given: every action input


def test_training_settings_keep_the_file_and_apply_overrides() -> None:
    settings = TrainingSettings.from_experiment(load_experiment(CARTPOLE), {"seed": 7, "n_envs": None})
    assert (settings.algo, settings.timesteps, settings.n_envs, settings.seed) == ("PPO", 150000, 8, 7)
    assert settings.hyperparams["learning_rate"] == "lin_0.001"
    with pytest.raises(ConfigError, match=r"training\.n_envs: .*\(got 0\)"):
        TrainingSettings.from_experiment(load_experiment(CARTPOLE), {"n_envs": 0})


def test_normalize_passes_only_the_keys_given(tmp_path: Path) -> None:
    path = with_changes(tmp_path, CARTPOLE, training={"normalize": {"norm_reward": False, "clip_obs": 5.0}})
    settings = TrainingSettings.from_experiment(load_experiment(path), {})
    assert settings.normalize_kwargs() == {"norm_reward": False, "clip_obs": 5.0}
    assert settings.normalize_kwargs(eval_env=True) == {"clip_obs": 5.0}
    assert (
        TrainingSettings.from_experiment(load_experiment(CARTPOLE), {"normalize": True}).normalize_kwargs()
        == {}
    )


def test_baselines_give_the_policies_what_the_file_says() -> None:
    settings = baseline_settings(load_experiment(MOTOR))
    assert settings["pid"]["kp"] == 2.0 and "value" not in settings["pid"]
    assert PidSpec.model_validate(settings["pid"]).limits == (-24.0, 24.0)
    assert set(PidSpec.model_fields) - {"type"} == set(PID_KEYS)  # one list of PID keys in both places


@pytest.mark.parametrize(
    ("baseline", "expected"),
    [
        ({"type": "constant"}, r"a constant baseline needs \['value'\]"),
        ({"type": "constant", "value": 1.0, "kp": 2.0}, r"\['kp'\] do not apply to a constant baseline"),
        ({"output": "omega", "reference": "omega_ref"}, r"a pid baseline needs \['input'\]"),
        ({"type": "python", "callable": "nocolon"}, r"expected 'module:function'"),
        ({"type": "pidd"}, r"\.type: .*\(got 'pidd'\)"),
        ({"type": "lqr"}, r"a lqr baseline needs \['design'\]"),
        (
            {"type": "lqr", "design": {"inputs": ["u"], "measured": ["y"]}, "kp": 1.0},
            r"\['kp'\] do not apply to a lqr",
        ),
    ],
)
def test_a_baseline_takes_the_keys_of_its_type(
    tmp_path: Path, baseline: dict[str, Any], expected: str
) -> None:
    path = with_changes(tmp_path, MOTOR, evaluation={"baselines": {"b": baseline}})
    with pytest.raises(ConfigError, match=expected):
        load_experiment(path)


def test_names_in_metrics_and_baselines_are_checked_against_the_fmu(tmp_path: Path) -> None:
    data = yaml.safe_load(MOTOR.read_text())
    data["evaluation"]["metrics"]["tracking"] = [["omegaa", "omega_ref"]]
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(
        ConfigError, match=r"evaluation\.metrics\.tracking\[0\] \(output\): 'omegaa' .* did you mean"
    ):
        check_with_model(load_experiment(path))
    data = yaml.safe_load(MOTOR.read_text())
    data["evaluation"]["baselines"]["pid"]["input"] = "current"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(
        ConfigError, match=r"evaluation\.baselines\.pid\.input: 'current' is not an action input"
    ):
        check_with_model(load_experiment(path))


def test_residual_needs_a_baseline_of_the_file(tmp_path: Path) -> None:
    path = with_changes(tmp_path, MOTOR, training={"residual": {"baseline": "pdi", "scale": 6.0}})
    with pytest.raises(
        ConfigError, match=r"training\.residual\.baseline: 'pdi' is not in evaluation\.baselines"
    ):
        load_experiment(path)
    path = with_changes(tmp_path, MOTOR, training={"residual": {"baseline": "pid", "scale": 0.0}})
    with pytest.raises(ConfigError, match=r"training\.residual\.scale: .*\(got 0\.0\)"):
        load_experiment(path)


def test_the_ros_section_is_the_ros_view_settings(tmp_path: Path) -> None:
    assert RosViewSettings is RosSection
    path = with_changes(tmp_path, MOTOR, ros={"domain_id": 7, "per_variable": True})
    section = load_experiment(path).ros
    view = settings_from(section.model_dump(exclude_unset=True), backend="zenoh")
    assert (view.domain_id, view.per_variable, view.backend) == (7, True, "zenoh")
    with pytest.raises(ConfigError, match=r"ros\.domain_id: .*\(got 999\)"):
        settings_from({"domain_id": 999})


def test_the_node_section_sets_the_defaults_of_fmu_bridge_node(tmp_path: Path) -> None:
    path = with_changes(tmp_path, MOTOR, node={"name": "motor-1", "mode": "realtime", "rate": 0.0})
    node = load_experiment(path).node
    assert (node.name, node.mode, node.rate, node.prefix) == ("motor-1", "realtime", 0.0, "fmu_bridge")
    with pytest.raises(ConfigError, match=r"node\.mode: .*\(got 'fast'\)"):
        load_experiment(with_changes(tmp_path, MOTOR, node={"mode": "fast"}))


def test_the_recording_section_decides_where_and_how_simulate_records(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from typer.testing import CliRunner

    from bridge.cli.main import app

    folder = tmp_path / "recs"
    path = with_changes(
        tmp_path, CARTPOLE, recording={"directory": str(folder), "compression": "none", "chunk_size": 4096}
    )
    result = CliRunner().invoke(app, ["simulate", str(path)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output + repr(result.exception)
    (recording,) = folder.glob("*.mcap")
    with recording.open("rb") as stream:
        chunks = list(make_reader(stream).get_summary().chunk_indexes)  # type: ignore[union-attr]
    assert len(chunks) > 1  # 500 samples of a few hundred bytes do not fit one 4 KiB chunk
    assert {c.compression for c in chunks} == {""}
