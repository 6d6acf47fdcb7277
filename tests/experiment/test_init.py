"""``init`` on the shapes other tools export, and configs over names, locals and FMI 3.0 array elements."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.init import _num, discrete_levels, q, starting_config
from bridge.experiment.validate import check_experiment
from bridge.fmu import read_model_info
from bridge.fmu.vocab import Variable

NASTY = [
    "a.b[1]",
    "der(x)",
    "'quoted name'",
    'say "hi"',
    "x: y # z",
    "- [1, {2}]",
    "ünï",
    "tab\there",
    "&*!|>%@`",
]


@pytest.mark.parametrize("name", NASTY)
def test_quoted_names_read_back_unchanged(name: str) -> None:
    assert yaml.safe_load(f"k: {q(name)}") == {"k": name}
    assert yaml.safe_load(f"{q(name)}: 1") == {name: 1}
    assert yaml.safe_load(f"k: [{q(name)}, {q(name)}]") == {"k": [name, name]}


def _var(type_: str, **kw: object) -> Variable:
    base: dict[str, object] = dict(
        name="u",
        value_reference=1,
        type=type_,
        causality="input",
        variability="discrete",
        initial=None,
        start=0,
    )
    return Variable(**{**base, **kw})  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [1e-06, -1e-06, 1e16, 2.5e-07, 1e300, 5e-324, 0.1, -3.0, 0.0])
def test_numbers_are_floats_to_yaml_1_1_readers(value: float) -> None:
    text = _num(value)
    read = yaml.safe_load(f"x: {text}")["x"]  # PyYAML follows YAML 1.1: 1e-06 would be a string
    assert isinstance(read, float) and read == value, text


def test_discrete_levels_respect_type_range_and_items() -> None:
    assert discrete_levels(_var("Boolean"))[0] == [0, 1]
    assert discrete_levels(_var("UInt8", start=255))[0] == [254, 255]  # never above the type's range
    assert discrete_levels(_var("Int32", min=-2, max=2))[0] == [-2, -1, 0, 1, 2]
    assert discrete_levels(_var("Int32", min=0, max=1000, start=7))[0] == [0, 7, 1000]
    items = (("off", 1), ("eco", 2), ("boost", 3))
    assert discrete_levels(_var("Enumeration", enum_items=items))[0] == [1, 2, 3]


def test_typed_inputs_become_levels_inside_their_ranges_and_check_passes(
    typed_fmu3: Path, tmp_path: Path
) -> None:
    """Before: every Int/Boolean input was a continuous action in [-1, 1] and the first step failed."""
    config = tmp_path / "e.yaml"
    config.write_text(starting_config(typed_fmu3, relative_to=tmp_path))
    (policy_line,) = [line for line in config.read_text().splitlines() if "reset_policy:" in line]
    assert "restore | reset | reinstantiate | auto" in policy_line  # the comment names every policy
    # typed has String and Binary variables, so it cannot serialise its state: no state_file offered
    assert "{state_file: PATH}" not in policy_line
    assert "no state_file: this FMU cannot save its state to a file" in config.read_text()
    exp = load_experiment(config)
    info = check_experiment(exp, read_model_info(typed_fmu3))
    with FmuEnv(config) as env:
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
    if exp.actions.type == "multi_discrete":
        for name, levels in exp.actions.levels.items():
            var = info.variables[name]
            assert all(float(x).is_integer() for x in levels)
            assert var.min is None or min(levels) >= var.min
            assert var.max is None or max(levels) <= var.max


@pytest.mark.integration  # a Python-backed FMU: it runs in a child process by default
def test_locals_only_model_with_modelica_names_is_observed_and_simulated(
    names2: Path, tmp_path: Path
) -> None:
    config = tmp_path / "e.yaml"
    config.write_text(starting_config(names2, relative_to=tmp_path))
    data = yaml.safe_load(config.read_text())
    assert data["actions"] == {"inputs": []}
    assert data["observations"]["outputs"][:2] == ["body.frame_a.r_0[1]", "body.frame_a.r_0[2]"]
    with FmuEnv(config) as env:
        assert env.action_space.shape == (0,)
        obs, _ = env.reset(seed=0)
        for _ in range(10):
            obs, *_ = env.step(np.zeros(0, dtype=np.float32))
        # 10 steps of 0.01 s on a unit circle at 1 rad/s: an independent closed form
        assert obs[:2] == pytest.approx([np.cos(0.1), np.sin(0.1)], abs=1e-6)


@pytest.mark.integration  # a Python-backed FMU: it runs in a child process by default
def test_evaluate_with_the_zero_policy_on_an_observation_only_experiment(
    names2: Path, tmp_path: Path
) -> None:
    from agents.evaluate import evaluate

    config = tmp_path / "e.yaml"
    config.write_text(starting_config(names2, relative_to=tmp_path))
    result = evaluate(["zero"], config, episodes=1)
    assert len(result.rows) == 1, result.rows
    assert "zero" in json.dumps(result.rows, default=str)


def test_hand_written_config_may_observe_locals_and_states(names2: Path, tmp_path: Path) -> None:
    config = tmp_path / "e.yaml"
    config.write_text(
        f"model: {{fmu: {q(str(names2))}, episode_duration: 1.0, step_size: 0.1}}\n"
        'observations: {outputs: ["der(body.frame_a.r_0[2])"]}\n'
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    check_experiment(load_experiment(config), read_model_info(names2))


def _arrays_config(tmp_path: Path, fmu: Path, inputs: str, outputs: str) -> Path:
    config = tmp_path / "a.yaml"
    config.write_text(
        f"model: {{fmu: {q(str(fmu))}, episode_duration: 1.0, step_size: 0.1}}\n"
        f'actions: {{inputs: {inputs}, low: {{"u[2]": -5.0}}, high: {{"u[2]": 5.0}}}}\n'
        f"observations: {{outputs: {outputs}, scale: none}}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return config


@pytest.mark.integration  # a Python-backed FMU: it runs in a child process by default
def test_config_naming_an_array_element_runs_and_a_whole_array_is_refused(
    arrays3_fmu: Path, tmp_path: Path
) -> None:
    """Before: a config naming a whole array passed the check and failed when the env was built."""
    whole = _arrays_config(tmp_path, arrays3_fmu, '["u[2]"]', '["y"]')
    with pytest.raises(ConfigError, match=r"'y' is an FMI 3.0 array Float64\[2,3\].*y\[1,1\]"):
        check_experiment(load_experiment(whole), read_model_info(arrays3_fmu))
    text = whole.read_text().replace('["y"]', '["y[1,2]", "y[2,2]"]')
    whole.write_text(text)
    with FmuEnv(whole) as env:
        env.reset(seed=0)
        obs, *_ = env.step(np.array([0.5], dtype=np.float32))  # u[2] = 2.5
        assert obs.tolist() == pytest.approx([2.5, 10 * 2.5 + 0.1])


# -- the name init writes is one check accepts ---------------------------------------------------
MODEL_NAMES = [
    "van der pol oscillator",
    "robertson problem",
    "Modelica.Blocks.Examples.PID_Controller",
    "(weird) name/with\\slashes and ..dots",
    "ünïcode model",
    "...",
]


def _literal(text: str) -> Callable[[re.Match[str]], str]:
    return lambda _: text


def _renamed(fmu: Path, model_name: str, folder: Path) -> Path:
    """A copy of ``fmu`` whose modelDescription.xml says ``modelName=model_name``."""
    import zipfile
    from xml.sax.saxutils import quoteattr

    target = folder / "renamed.fmu"
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(target, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = re.sub(
                    r'modelName="[^"]*"', _literal(f"modelName={quoteattr(model_name)}"), data.decode()
                )
                data = text.encode()
            dst.writestr(item, data)
    return target


@pytest.mark.parametrize("model_name", MODEL_NAMES)
def test_init_writes_a_name_check_accepts_whatever_the_model_is_called(
    cartpole_fmu: Path, tmp_path: Path, model_name: str
) -> None:
    """Before: init wrote the model's name as is and check refused any with a space."""
    fmu = _renamed(cartpole_fmu, model_name, tmp_path)
    assert read_model_info(fmu).model_name == model_name
    config = tmp_path / "e.yaml"
    config.write_text(starting_config(fmu, relative_to=tmp_path))
    exp = load_experiment(config)
    check_experiment(exp, read_model_info(fmu))
    assert exp.name and exp.name[0].isalnum() and " " not in exp.name
    with FmuEnv(config) as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())


def _cached_fmus() -> list[Path]:
    """Every FMU archive the tests have cached so far (example models, third-party downloads)."""
    import os

    root = Path(os.environ.get("FMU_BRIDGE_CACHE", Path.home() / ".cache" / "fmu-bridge"))
    return sorted(root.rglob("*.fmu")) if root.is_dir() else []


def _with_suggestions(text: str) -> dict[str, Any]:
    """The config ``init`` wrote, with the parameter defaults it suggests in comments given."""
    data: dict[str, Any] = yaml.safe_load(text)
    suggested = {}
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("  parameters: {}")), len(lines))
    for line in lines[start + 1 :]:
        if not line.lstrip().startswith("#"):
            break
        if line.startswith("  #   "):  # '  #   "name": value  # description'
            suggested.update(yaml.safe_load("{" + line[6:].split("  #")[0] + "}"))
    data["model"]["parameters"] = {**(data["model"].get("parameters") or {}), **suggested}
    return data


def test_init_writes_names_and_values_check_accepts_for_every_cached_fmu(tmp_path: Path) -> None:
    """Every FMU the tests have cached: the config as written, and with every suggested value."""
    fmus = _cached_fmus()
    if not fmus:
        pytest.skip("no FMU cached yet under FMU_BRIDGE_CACHE")
    for i, fmu in enumerate(fmus):
        config = tmp_path / f"e{i}.yaml"
        text = starting_config(fmu, relative_to=tmp_path)
        config.write_text(text)
        check_experiment(load_experiment(config), read_model_info(fmu))
        config.write_text(yaml.safe_dump(_with_suggestions(text)))
        check_experiment(load_experiment(config), read_model_info(fmu))


def test_init_suggests_an_array_parameter_by_its_elements_and_the_model_takes_them(tmp_path: Path) -> None:
    """Before: init suggested ``"A": "1 0 0 1"`` (the XML's start string), which nothing accepts."""
    from bridge.models.strict import strict_arrays_fmu

    fmu = strict_arrays_fmu()
    data = _with_suggestions(starting_config(fmu, relative_to=tmp_path))
    assert {k: v for k, v in data["model"]["parameters"].items() if k.startswith("A")} == {
        "A[1,1]": 1.0,
        "A[1,2]": 0.0,
        "A[2,1]": 0.0,
        "A[2,2]": 1.0,
    }
    config = tmp_path / "e.yaml"
    config.write_text(yaml.safe_dump(data))
    check_experiment(load_experiment(config), read_model_info(fmu))
    with FmuEnv(config) as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())
