"""The CLI and experiments on ``modelica_names``, our FMU with the names a Modelica tool exports.

``init`` must write YAML that names ``'force in N'``, ``body.frame_a.r_0[1]`` and ``spring.c``
exactly; an experiment acts on the quoted input and observes an output and two locals, one named
with ``<``, ``&`` and ``\\"``; ``inspect`` prints every name in full, also at 80 columns and as JSON.
Expected values come from the closed-form harmonic oscillator and from the XML read with ElementTree.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.init import q
from bridge.models import example_fmu

VARIANTS = [("2.0", "cs"), ("2.0", "me"), ("3.0", "cs")]
FORCE, SPRING, R0 = "'force in N'", "spring.'f = -c*s'", "body.frame_a.r_0[1]"
ENERGY = "'energy <J> & \\\"total\\\"'"
runner = CliRunner()


def _fmu(variant: tuple[str, str]) -> Path:
    return example_fmu("modelica_names", *variant)


def _xml_names(fmu: Path) -> list[str]:
    root = ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    return [str(v.get("name")) for v in root.findall("./ModelVariables/*")]


@pytest.mark.parametrize("variant", VARIANTS, ids="-".join)
def test_init_writes_yaml_naming_the_modelica_variables(variant: tuple[str, str], tmp_path: Path) -> None:
    config = tmp_path / "e.yaml"
    result = runner.invoke(app, ["init", str(_fmu(variant)), "-o", str(config)])
    assert result.exit_code == 0, result.output
    text = config.read_text()
    data = yaml.safe_load(text)
    assert data["actions"]["inputs"] == [FORCE]
    assert data["actions"]["low"] == {FORCE: -10.0} and data["actions"]["high"] == {FORCE: 10.0}
    assert data["observations"]["outputs"] == [R0]
    for name, value in (("body.m", 1.0), ("spring.c", 4.0), ("body.s_start", 1.0)):
        assert f"#   {q(name)}: {value}" in text  # the parameters, listed for the user to copy


def _experiment(tmp_path: Path, fmu: Path) -> Path:
    config = tmp_path / "names.yaml"
    observed = ", ".join(q(n) for n in (R0, SPRING, ENERGY))
    config.write_text(
        f"model: {{fmu: {q(str(fmu))}, episode_duration: 1.0, step_size: 0.01}}\n"
        f"actions: {{inputs: [{q(FORCE)}], low: {{{q(FORCE)}: -10.0}}, high: {{{q(FORCE)}: 10.0}}}}\n"
        f"observations: {{outputs: [{observed}], scale: none}}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return config


@pytest.mark.parametrize("variant", VARIANTS, ids="-".join)
def test_experiment_acts_on_the_quoted_input_and_observes_an_output_and_locals(
    variant: tuple[str, str], tmp_path: Path
) -> None:
    force, action = 1.5, np.array([0.15], dtype=np.float32)  # [-1, 1] onto [-10, 10] N
    t = 0.01 * np.arange(1, 51)
    s = force / 4.0 + (1.0 - force / 4.0) * np.cos(2.0 * t)  # m s'' = -c s + F, s(0) = 1, s'(0) = 0
    v = -(1.0 - force / 4.0) * 2.0 * np.sin(2.0 * t)
    expected = np.column_stack([s, -4.0 * s, 0.5 * v**2 + 2.0 * s**2])
    with FmuEnv(_experiment(tmp_path, _fmu(variant))) as env:
        for _ in range(2):  # the second episode replays the first
            obs, _ = env.reset(seed=0)
            assert obs == pytest.approx([1.0, -4.0, 2.0], abs=1e-6)
            seen = np.array([env.step(action)[0] for _ in t])
            assert np.max(np.abs(seen - expected)) < 1e-5, np.max(np.abs(seen - expected), axis=0)


@pytest.mark.parametrize("variant", VARIANTS, ids="-".join)
def test_inspect_prints_every_name_in_full_at_80_columns_and_as_json(variant: tuple[str, str]) -> None:
    fmu, env = _fmu(variant), {"COLUMNS": "80", "TERM": "dumb"}
    names = _xml_names(fmu)
    assert ENERGY in names and FORCE in names and R0 in names
    plain = runner.invoke(app, ["inspect", str(fmu)], env=env)
    assert plain.exit_code == 0, plain.output
    lines = plain.output.splitlines()
    assert all(name in lines for name in names), [n for n in names if n not in lines]
    as_json = runner.invoke(app, ["inspect", str(fmu), "--json"], env=env)
    assert as_json.exit_code == 0, as_json.output
    assert [v["name"] for v in json.loads(as_json.output)["variables"]] == names
