"""Experiment files: every config error names the key, the bad value, what is allowed, and the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, load_experiment, parse_experiment
from bridge.experiment.examples import example_experiment, example_names
from bridge.experiment.validate import check_experiment
from bridge.plant.factory import model_info_for


def base(**overrides: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "model": {"fmu": "example:dcmotor", "step_size": 0.01, "episode_duration": 1.0},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    for key, value in overrides.items():
        section, _, field = key.partition("__")
        if field:
            data[section] = {**data.get(section, {}), field: value}
        else:
            data[section] = value
    return data


def write(tmp_path: Path, data: dict[str, Any]) -> Path:
    path = tmp_path / "experiment.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def check_with_fmu(experiment: Experiment) -> None:
    check_experiment(experiment, model_info_for(experiment))


def check(tmp_path: Path, data: dict[str, Any]) -> None:
    check_with_fmu(load_experiment(write(tmp_path, data)))


@pytest.mark.parametrize("name", example_names())
def test_examples_are_valid(name: str) -> None:
    check_with_fmu(load_experiment(example_experiment(name)))


def test_variable_not_in_the_fmu(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        check(tmp_path, base(observations={"outputs": ["omegaa"]}))
    message = str(caught.value)
    assert "observations.outputs: 'omegaa' is not a variable of the FMU" in message
    assert "did you mean ['omega'" in message and str(tmp_path / "experiment.yaml") in message


def test_sampling_time_not_a_whole_number_of_fmu_steps(tmp_path: Path) -> None:
    data = base(model__sampling_time=0.025)
    with pytest.raises(
        ConfigError, match=r"model\.sampling_time: 0\.025 s is not a whole number of FMU steps of 0\.01 s"
    ):
        check(tmp_path, data)


def test_non_finite_action_bound(tmp_path: Path) -> None:
    data = base(actions={"inputs": ["load_torque"]})  # the FMU declares no min/max for it
    with pytest.raises(
        ConfigError, match=r"actions\.low\.load_torque: the low bound is None.*set actions\.low"
    ):
        check(tmp_path, data)
    data = base(actions={"inputs": ["voltage"], "high": {"voltage": float("inf")}})
    with pytest.raises(ConfigError, match=r"actions\.high\.voltage: .*finite"):
        check(tmp_path, data)


def test_unknown_reward_term(tmp_path: Path) -> None:
    data = base(reward={"terms": [{"bonus": 1.0}]})
    with pytest.raises(ConfigError) as caught:
        check(tmp_path, data)
    assert "reward.terms[0]" in str(caught.value)
    assert "unknown reward term 'bonus'; known terms: alive, tracking, effort, rate, signal" in str(
        caught.value
    )


def test_input_used_as_observation(tmp_path: Path) -> None:
    data = base(observations={"outputs": ["omega", "voltage"]})
    with pytest.raises(ConfigError, match=r"'voltage' is an input of the FMU.*include_action"):
        check(tmp_path, data)


def test_unknown_key_is_rejected_with_its_path(tmp_path: Path) -> None:
    data = base(model__step_sise=0.01)
    with pytest.raises(ConfigError, match=r"model\.step_sise: unknown key"):
        check(tmp_path, data)


def test_action_input_that_is_an_output(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match=r"actions\.inputs: 'omega' has causality 'output' in the FMU, not 'input'"
    ):
        check(tmp_path, base(actions={"inputs": ["omega"], "low": {"omega": 0}, "high": {"omega": 1}}))


def test_calculated_parameter_cannot_be_randomised(tmp_path: Path) -> None:
    data = base(randomization={"parameters": {"torque": {"uniform": [0, 1]}}})
    with pytest.raises(ConfigError, match=r"randomization\.parameters: 'torque' is a continuous output"):
        check(tmp_path, data)


def test_reference_missing_from_a_scenario(tmp_path: Path) -> None:
    data = base(
        observations={"outputs": ["omega"], "references": ["omega_ref"]},
        scenarios={"a": {"references": {"omega_ref": 10.0}}, "b": {}},
    )
    with pytest.raises(ConfigError, match=r"scenarios \['b'\] do not define it"):
        check(tmp_path, data)


def test_bad_distribution_and_profile(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"uniform: low must not exceed high"):
        check(tmp_path, base(randomization={"parameters": {"J": {"uniform": [2, 1]}}}))
    with pytest.raises(ConfigError, match=r"give exactly one of constant, step"):
        check(
            tmp_path,
            base(
                scenarios={
                    "s": {
                        "inputs": {
                            "load_torque": {
                                "step": {"time": 1, "after": 1},
                                "sine": {"amplitude": 1, "frequency_hz": 1},
                            }
                        }
                    }
                }
            ),
        )


def test_expression_with_unknown_name(tmp_path: Path) -> None:
    data = base(reward={"expression": "-abs(omegaa)"})
    with pytest.raises(ConfigError, match=r"omegaa"):
        FmuEnv(load_experiment(write(tmp_path, data)))


def test_expression_cannot_run_code(tmp_path: Path) -> None:
    data = base(reward={"expression": "__import__('os').system('true')"})
    with pytest.raises(ConfigError):
        FmuEnv(load_experiment(write(tmp_path, data)))


def test_unknown_version_lists_defined_ones() -> None:
    with pytest.raises(ConfigError, match=r"version 'v9' is not defined.*\['v0', 'v1'\]"):
        load_experiment(example_experiment("cartpole_balance"), version="v9")


def test_fmu_path_is_relative_to_the_experiment_file(tmp_path: Path) -> None:
    data = base(model__fmu="models/missing.fmu")
    with pytest.raises(ConfigError, match=r"model\.fmu: 'models/missing\.fmu' does not exist"):
        check(tmp_path, data)


def test_yaml_syntax_error_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("model: [unclosed\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml: not valid YAML"):
        load_experiment(path)


def test_experiment_is_frozen() -> None:
    experiment = parse_experiment(base())
    with pytest.raises(Exception, match="frozen"):
        experiment.model.step_size = 1.0  # type: ignore[misc]


def test_a_fixed_step_solver_needs_model_exchange(tmp_path: Path) -> None:
    data = base()
    data["model"].update(interface="cs", solver="rk4")
    with pytest.raises(
        ConfigError, match=r"model\.solver: 'rk4' integrates model exchange, but interface is 'cs'"
    ):
        load_experiment(write(tmp_path, data))
    data["model"].update(interface="me", solver_substeps=0)
    with pytest.raises(ConfigError, match=r"model\.solver_substeps: .*\(got 0\)"):
        load_experiment(write(tmp_path, data))
    data["model"].update(solver_substeps=50)
    loaded = load_experiment(write(tmp_path, data))
    assert (loaded.model.solver, loaded.model.solver_substeps) == ("rk4", 50)
    env = FmuEnv(loaded)
    assert env.plant.model.solver == "rk4"  # type: ignore[attr-defined]  # the plant's Model got it
    env.close()
