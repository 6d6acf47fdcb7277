"""The fixed policies of ``simulate`` and ``check`` say it when they change what the user asked:
physical values reach the FMU exactly, a value out of bounds is clipped with one warning naming the
value, the bound and the variable, ``zero`` leaves tunable parameters at the FMU's start values, and
a policy for a model without actions is refused; ``start`` runs the model as exported, as FMPy's
default simulation does."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.cli.simulate import make_policy
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.init import starting_config
from bridge.models import example_fmu


def _env(tmp_path: Path, model: str, actions: str, outputs: str) -> FmuEnv:
    path = tmp_path / f"{model}.yaml"
    path.write_text(
        f"model: {{fmu: '{example_fmu(model, '2.0', 'cs')}', step_size: 0.01, sampling_time: 0.01, "
        "episode_duration: 0.1}\n"
        f"actions: {actions}\n"
        f"observations: {{outputs: {outputs}}}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return FmuEnv(path)


FEEDTHROUGH = "{inputs: [u], low: {u: 0.1}, high: {u: 2.3}}"  # centre 1.2, half range 1.1


@pytest.mark.parametrize("value", [0.9, 0.1, 2.3, 1.2345678901234567, 0.30000000000000004])
def test_a_constant_reaches_the_fmu_exactly(tmp_path: Path, value: float) -> None:
    with _env(tmp_path, "feedthrough", FEEDTHROUGH, "[y]") as env:
        policy = make_policy(f"constant:{value!r}", env.task, 0)
        obs, _ = env.reset(seed=0)
        for _ in range(2):
            obs, *_, info = env.step(policy(obs))
            assert env.task.applied_inputs[0] == value
        assert info["outputs"][0] == value  # y is u as the FMU received it


def test_a_clipped_constant_warns_once_with_value_bound_and_variable(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with _env(tmp_path, "feedthrough", FEEDTHROUGH, "[y]") as env, caplog.at_level(logging.WARNING):
        policy = make_policy("constant:2.5", env.task, 0)
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            obs, *_ = env.step(policy(obs))
        assert env.task.applied_inputs[0] == 2.3
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, warnings
    assert "2.5 on u is outside its bounds [0.1, 2.3]: its maximum 2.3 is applied instead" in warnings[0]


def test_zero_keeps_a_tunable_parameter_at_the_fmu_start_value(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with _env(tmp_path, "pi_controller", "{inputs: [kp], low: {kp: 0.5}, high: {kp: 3.0}}", "[u]") as env:
        with caplog.at_level(logging.WARNING):
            policy = make_policy("zero", env.task, 0)
        obs, _ = env.reset(seed=0)
        env.step(policy(obs))
        assert env.task.applied_inputs[0] == 1.0  # kp's start value, not 0 clipped to 0.5
    assert not caplog.records


def test_zero_on_an_input_is_zero(tmp_path: Path) -> None:
    with _env(tmp_path, "feedthrough", "{inputs: [u], low: {u: -1.0}, high: {u: 3.0}}", "[y]") as env:
        policy = make_policy("zero", env.task, 0)
        obs, _ = env.reset(seed=0)
        env.step(policy(obs))
        assert env.task.applied_inputs[0] == 0.0


@pytest.mark.parametrize("spec", ["constant:2.5", "random"])
def test_a_policy_for_a_model_without_actions_is_refused(tmp_path: Path, spec: str) -> None:
    with _env(tmp_path, "bouncing_ball", "{inputs: []}", "[h]") as env:
        with pytest.raises(ConfigError, match=r"has no actions \(actions\.inputs is empty\)"):
            make_policy(spec, env.task, 0)
        policy = make_policy("zero", env.task, 0)  # nothing applied: observation only
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(policy(obs))
        assert np.isfinite(obs).all()


@pytest.fixture(scope="module")
def vehicle_as_exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``init``'s experiment for the vehicle: its speed input starts at 15 m/s, not 0."""
    path = tmp_path_factory.mktemp("start") / "vehicle.yaml"
    path.write_text(starting_config(example_fmu("vehicle", "2.0", "cs")))
    return path


def _trajectory(path: Path, spec: str, samples: int) -> tuple[np.ndarray, list[str]]:
    with FmuEnv(path) as env:
        policy = make_policy(spec, env.task, 0)
        obs, _ = env.reset(seed=0)
        rows = []
        for _ in range(samples):
            obs, *_, info = env.step(policy(obs))
            rows.append(np.asarray(info["outputs"], dtype=np.float64))
        return np.array(rows), list(env.output_names)


def test_start_runs_the_model_as_fmpys_default_simulation(vehicle_as_exported: Path) -> None:
    samples, step_s = 40, 0.05
    ours, names = _trajectory(vehicle_as_exported, "start", samples)
    fmu = str(example_fmu("vehicle", "2.0", "cs"))
    fmpy = simulate_fmu(
        fmu,
        fmi_type="CoSimulation",
        step_size=step_s,
        output_interval=step_s,
        stop_time=samples * step_s,
        output=names,
    )
    theirs = np.array([[row[name] for name in names] for row in fmpy[1 : samples + 1]])
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
    assert theirs[-1, names.index("distance")] > 25.0  # it drove at its start speed of 15 m/s
    zero, _ = _trajectory(vehicle_as_exported, "zero", samples)
    assert not np.allclose(zero, theirs)  # zero stops the car: not the model as exported


def test_check_shows_the_steps_of_the_start_policy(vehicle_as_exported: Path) -> None:
    shown = CliRunner().invoke(app, ["check", str(vehicle_as_exported), "--policy", "start", "--steps", "2"])
    assert shown.exit_code == 0, shown.output
    assert "first steps (start action" in shown.output
    refused = CliRunner().invoke(app, ["check", str(vehicle_as_exported), "--policy", "stat"])
    assert isinstance(refused.exception, ConfigError)  # the CLI's entry point prints it as one line
    assert "use zero, start, random or constant:VALUE" in str(refused.exception)


def test_start_on_a_model_without_actions_applies_nothing(tmp_path: Path) -> None:
    with _env(tmp_path, "bouncing_ball", "{inputs: []}", "[h]") as env:
        policy = make_policy("start", env.task, 0)
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(policy(obs))
        assert np.isfinite(obs).all()
