"""Hostile experiment files: anchor bombs, deep nesting, infinities, reversed bounds, absurd lengths.

Each case once ended in a traceback, a huge allocation or a silently accepted file; each now is a
ConfigError naming the key, the value, what is allowed and the file.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
import yaml

from bridge.errors import ConfigError
from bridge.experiment.config import MAX_SAMPLES, load_experiment
from bridge.experiment.examples import example_experiment
from bridge.experiment.yaml_text import MAX_DEPTH, parse_yaml
from tests.conftest import check_with_model

CARTPOLE = example_experiment("cartpole_balance")
MOTOR = example_experiment("dcmotor_tracking")


def edited(tmp_path: Path, source: Path, old: str, new: str) -> Path:
    text = source.read_text()
    assert old in text, old
    path = tmp_path / source.name
    path.write_text(text.replace(old, new, 1))
    return path


def rejected(path: Path) -> str:
    with pytest.raises(ConfigError) as caught:
        check_with_model(load_experiment(path))
    message = str(caught.value)
    assert str(path) in message, message
    return message


def billion_laughs(levels: int = 9) -> str:
    lines = ["    l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"    l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, levels + 1)]
    return "\n".join(lines)


def test_an_anchor_bomb_in_training_fails_at_once(tmp_path: Path) -> None:
    path = edited(tmp_path, CARTPOLE, "  hyperparams:\n", "  hyperparams:\n" + billion_laughs() + "\n")
    started = time.perf_counter()
    message = rejected(path)
    assert time.perf_counter() - started < 10.0  # expanding it would take minutes and gigabytes
    assert "aliases (*name) repeating anchors (&name) expand this YAML to" in message
    expanded = re.search(r"expand this YAML to ([\d,]+) values", message)
    assert expanded is not None and int(expanded[1].replace(",", "")) > 4 * 10**9  # 10^9 "lol"s


def test_small_anchors_and_merge_keys_still_work(tmp_path: Path) -> None:
    text = CARTPOLE.read_text()
    text = text.replace("    x: [-2.4, 2.4]", "    x: &track [-2.4, 2.4]", 1)
    text += "\nnode: &node {name: cart, rate: 0.0}\nros: {domain_id: 3}\n"
    text = text.replace("  n_envs: 8", "  n_envs: 8\n  remote: &remote {nodes: 'cart-*'}", 1)
    path = tmp_path / "anchors.yaml"
    path.write_text(text)
    experiment = load_experiment(path)
    assert experiment.termination.bounds["x"] == (-2.4, 2.4)
    assert experiment.node.name == "cart" and experiment.training.remote.nodes == "cart-*"
    assert parse_yaml("a: &a {x: 1}\nb: {<<: *a, y: 2}") == {"a": {"x": 1}, "b": {"x": 1, "y": 2}}


def test_a_recursive_alias_is_rejected(tmp_path: Path) -> None:
    path = edited(tmp_path, CARTPOLE, "  hyperparams:\n", "  hyperparams: &h\n    me: *h\n")
    assert "an alias refers to a node that contains it" in rejected(path)


@pytest.mark.parametrize(
    "text", ["a: " + "[" * 300_000 + "]" * 300_000, "a:\n" + "".join(f"{' ' * i}- \n" for i in range(1, 300))]
)
def test_deep_nesting_is_rejected_quickly_and_never_crashes_the_parser(text: str) -> None:
    started = time.perf_counter()
    with pytest.raises(ConfigError, match=rf"nested more than {MAX_DEPTH} levels deep"):
        parse_yaml(text)
    # a guard against a hang or a crash (libyaml composes recursively in C: depth is checked first),
    # not a speed measure: a loaded machine gets a wide margin (a quiet one takes well under a second)
    assert time.perf_counter() - started < 60.0


def test_a_huge_or_binary_file_is_a_config_error(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (1 << 20))
    assert "the limit is" in rejected(big)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"model: \xff\xfe\n")
    assert "not UTF-8 text" in rejected(binary)


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "- alive: 1.0\n  termination_penalty",
            "- signal: {name: x, scale: .inf}\n  termination_penalty",
            r"reward\.terms\[0\]\.signal\.scale: .*\(got inf\)",
        ),
        (
            "- alive: 1.0\n  termination_penalty",
            "- signal: {name: x, scale: .nan}\n  termination_penalty",
            r"reward\.terms\[0\]\.signal\.scale: .*\(got nan\)",
        ),
        (
            "  episode_duration: 10.0 ",
            "  episode_duration: .inf ",
            r"model\.episode_duration: .*\(got inf\)",
        ),
        (
            "  episode_duration: 10.0 ",
            "  episode_duration: 1e12 ",
            r"model\.episode_duration: 1e\+12 s at 0\.02 s per sample is 5e\+13 samples; at most 1e\+07",
        ),
        (
            "  reset_policy: auto",
            "  reset_policy: auto\n  tolerance: .inf",
            r"model\.tolerance: .*\(got inf\)",
        ),
        (
            "    x: [-2.4, 2.4]",
            "    x: [2.4, -2.4]",
            r"termination\.bounds\.x: need \[low, high\] with low < high, got \[2\.4, -2\.4\]",
        ),
        (
            "  reset_policy: auto",
            "  reset_policy: auto\n  parameters: {x0: .nan}",
            r"model\.parameters\.x0: .*\(got nan\)",
        ),
        (
            "  eval_every: 20000",
            "  eval_every: 20000\n  remote: {timeout_s: .inf}",
            r"training\.remote\.timeout_s: .*\(got inf\)",
        ),
    ],
)
def test_infinite_and_reversed_values_in_cartpole_are_rejected(
    tmp_path: Path, old: str, new: str, expected: str
) -> None:
    assert re.search(expected, rejected(edited(tmp_path, CARTPOLE, old, new)))


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "scale: 100.0}",
            "scale: .inf}",
            r"reward\.terms\[0\]\.tracking\.scale: .*\(got inf\)",
        ),
        (
            "    omega: [-250.0, 250.0]",
            "    omega: [250.0, -250.0]",
            r"observations\.scale\.omega: need \[low, high\] with low < high",
        ),
        (
            "    constraints: {current: [-30.0, 30.0]}",
            "    constraints: {current: [30.0, -30.0]}",
            r"evaluation\.metrics\.constraints\.current: need \[low, high\]",
        ),
        (
            "      limits: [-24.0, 24.0]",
            "      limits: [24.0, -24.0]",
            r"evaluation\.baselines\.pid\.limits: need \[low, high\] with low < high",
        ),
        (
            "    parameters: {J: 0.015}",
            "    parameters: {J: .inf}\n    episode_duration: .inf",
            r"scenarios\.heavy_load\.parameters\.J: .*\(got inf\)",
        ),
        (
            "    parameters: {J: 0.015}",
            "    episode_duration: 1e9",
            r"scenarios\.heavy_load\.episode_duration: 1e\+09 s at 0\.01 s per sample",
        ),
        (
            "  mode: random",
            "  mode: weighted\n  weights: {step_up: .inf}",
            r"schedule\.weights\.step_up: .*\(got inf\)",
        ),
    ],
)
def test_infinite_and_reversed_values_in_the_motor_are_rejected(
    tmp_path: Path, old: str, new: str, expected: str
) -> None:
    assert re.search(expected, rejected(edited(tmp_path, MOTOR, old, new)))


def test_reversed_action_bounds_are_rejected(tmp_path: Path) -> None:
    path = edited(
        tmp_path, example_experiment("cartpole_continuous"), "low: {force: -10.0}", "low: {force: 10.0}"
    )
    path.write_text(path.read_text().replace("high: {force: 10.0}", "high: {force: -10.0}"))
    assert "actions.low/high.force: need [low, high] with low < high, got [10.0, -10.0]" in rejected(path)


def test_the_sample_limit_also_holds_when_the_step_comes_from_the_fmu(tmp_path: Path) -> None:
    data = yaml.safe_load(CARTPOLE.read_text())
    del data["model"]["step_size"], data["model"]["sampling_time"]
    data["model"]["episode_duration"] = 1e12
    path = tmp_path / "nostep.yaml"
    path.write_text(yaml.safe_dump(data))
    message = rejected(path)
    assert (
        "model.episode_duration: 1e+12 s at" in message
        and f"at most {MAX_SAMPLES:.0e} per episode" in message
    )
