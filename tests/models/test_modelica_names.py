"""Modelica-style variable names in our own models: the generator and the ``modelica_names`` FMU.

The generator keeps the name for the XML (escaped by the XML writer) and derives a C identifier from
it, or takes one given as ``c``. The FMU, a mass on a spring, is driven by FMPy and compared with the
closed-form harmonic oscillator; its XML is read back with ElementTree, independently of FMPy.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

from bridge import models
from bridge.errors import BridgeError
from bridge.models import sources as model_sources
from bridge.models.ccode import _c_string
from bridge.models.spec import c_identifier

NAME = "modelica_names"
VARIANTS = [("2.0", "cs"), ("2.0", "me"), ("3.0", "cs")]
ENERGY = "'energy <J> & \\\"total\\\"'"  # a Modelica escape: the name holds backslash-quote
SPRING = "spring.'f = -c*s'"
OMEGA = 2.0  # sqrt(spring.c / body.m) with the defaults 4 N/m and 1 kg


def oscillator(t: np.ndarray, force: float, s0: float = 1.0, c: float = 4.0, m: float = 1.0) -> np.ndarray:
    """Position of m s'' = -c s + force with s(0) = s0, s'(0) = 0."""
    return force / c + (s0 - force / c) * np.cos(math.sqrt(c / m) * t)


@pytest.fixture(scope="module")
def fmus() -> dict[tuple[str, str], Path]:
    return {(v, i): models.example_fmu(NAME, v, i) for v, i in VARIANTS}


# --- the generator ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("x_dot", "x_dot"),
        ("der(x)", "der_x"),
        ("body.frame_a.r_0[1]", "body_frame_a_r_0_1"),
        ("der(body.frame_a.r_0[1])", "der_body_frame_a_r_0_1"),
        ("'force in N'", "force_in_N"),
        ("a[1,2].b", "a_1_2_b"),
        (ENERGY, "energy_J_total"),
    ],
)
def test_c_identifier_is_derived_from_the_name(name: str, expected: str) -> None:
    assert c_identifier(name) == expected


def _load(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, variables: list[dict[str, Any]]) -> Any:
    root = tmp_path / "models"
    (root / "common").mkdir(parents=True)
    shutil.copy(model_sources.models_root() / "common" / "units.json", root / "common")
    (root / "m").mkdir()
    described = [{"description": "", **v} for v in variables]
    spec = {"description": "t", "variants": {"2.0": ["cs"]}, "default_experiment": {}, "variables": described}
    (root / "m" / "model.json").write_text(json.dumps(spec))
    monkeypatch.setattr(model_sources, "models_root", lambda: root)
    return model_sources.load_spec("m")


@pytest.mark.parametrize(
    ("variables", "message"),
    [
        ([{"name": "a.b"}, {"name": "a_b"}], "'a_b' is also the one of a.b"),
        ([{"name": "'1st'"}], "'1st' is not a valid C identifier"),
        ([{"name": "'int'"}], "'int' is not a valid C identifier (or is a C keyword)"),
        ([{"name": "x", "c": "y z"}], "'y z' is not a valid C identifier"),
        ([{"name": "'caf\u00e9'"}], "must be non-empty printable ASCII"),
    ],
)
def test_names_without_a_usable_c_identifier_are_refused_saying_how_to_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, variables: list[dict[str, Any]], message: str
) -> None:
    with pytest.raises(BridgeError) as info:
        _load(tmp_path, monkeypatch, variables)
    assert message in str(info.value)
    if "C identifier" in message:
        assert 'the key "c"' in str(info.value)


def test_an_explicit_c_identifier_resolves_a_clash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    spec = _load(tmp_path, monkeypatch, [{"name": "a.b"}, {"name": "a_b", "c": "a_b2"}])
    assert [v.c_name for v in spec.variables] == ["time", "a_b", "a_b2"]


@pytest.mark.parametrize("text", ["a??=b??/c??'", 'say "hi" \\ no', ENERGY, "??)??(??!??<??>??-"])
def test_c_string_literals_compile_back_to_the_same_text(tmp_path: Path, text: str) -> None:
    """gcc -std=c99 reads trigraphs: every ? is escaped so that names such as 'a??=b' survive."""
    source = tmp_path / "s.c"
    main = f"int main(void) {{ fputs({_c_string(text)}, stdout); return 0; }}"
    source.write_text(f"#include <stdio.h>\n{main}\n")
    gcc = shutil.which("gcc") or pytest.skip("gcc is not installed")
    subprocess.run([gcc, "-std=c99", "-Wall", "-Werror", str(source), "-o", str(tmp_path / "s")], check=True)
    assert subprocess.run([str(tmp_path / "s")], capture_output=True, check=True).stdout.decode() == text


# --- the FMU ------------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS, ids="-".join)
def test_names_survive_the_xml_and_the_c_identifiers_are_the_derived_ones(
    fmus: dict[tuple[str, str], Path], variant: tuple[str, str]
) -> None:
    with zipfile.ZipFile(fmus[variant]) as archive:
        xml = archive.read("modelDescription.xml")
        header = archive.read("sources/model_gen.h").decode()
    assert b"name=\"'energy &lt;J&gt; &amp; \\&quot;total\\&quot;'\"" in xml
    root = ET.fromstring(xml)
    names = [v.get("name") for v in root.findall("./ModelVariables/*")]
    assert names[:7] == ["time", "'force in N'", "body.frame_a.r_0[1]", "body.s", "body.v", SPRING, ENERGY]
    assert names[-2:] == ["der(body.s)", "der(body.v)"] if variant[1] == "me" else "der(body.s)" not in names
    for define in ("VR_force_in_N 1", "VR_body_frame_a_r_0_1 2", "VR_f_spring 5", "VR_energy_J_total 6"):
        assert f"#define {define}\n" in header
    assert validate_fmu(str(fmus[variant])) == []


def test_model_exchange_declares_the_derivatives_of_the_states(fmus: dict[tuple[str, str], Path]) -> None:
    root = ET.fromstring(zipfile.ZipFile(fmus["2.0", "me"]).read("modelDescription.xml"))
    variables = root.findall("./ModelVariables/ScalarVariable")
    index = {v.get("name"): i for i, v in enumerate(variables, start=1)}
    derivative_of = {v.get("name"): v[0].get("derivative") for v in variables if v[0].get("derivative")}
    assert derivative_of == {"der(body.s)": str(index["body.s"]), "der(body.v)": str(index["body.v"])}
    listed = [u.get("index") for u in root.findall("./ModelStructure/Derivatives/Unknown")]
    assert listed == [str(index["der(body.s)"]), str(index["der(body.v)"])]


@pytest.mark.parametrize("variant", VARIANTS, ids="-".join)
def test_fmpy_trajectories_match_the_harmonic_oscillator(
    fmus: dict[tuple[str, str], Path], variant: tuple[str, str]
) -> None:
    force = 1.5
    result = simulate_fmu(
        str(fmus[variant]),
        stop_time=3.0,
        output_interval=0.05,
        relative_tolerance=1e-10,
        start_values={"'force in N'": force},
        output=["body.frame_a.r_0[1]", "body.s", "body.v", SPRING, ENERGY],
    )
    t, s = result["time"], oscillator(result["time"], force)
    v = -(1.0 - force / 4.0) * OMEGA * np.sin(OMEGA * t)
    tolerance = 1e-6 if variant[1] == "me" else 1e-9  # CVode at rtol 1e-10; RK4 with 1 ms substeps
    assert np.max(np.abs(result["body.frame_a.r_0[1]"] - s)) < tolerance
    assert np.max(np.abs(result["body.s"] - s)) < tolerance
    assert np.max(np.abs(result["body.v"] - v)) < tolerance
    assert np.max(np.abs(result[SPRING] + 4.0 * s)) < 4 * tolerance
    assert np.max(np.abs(result[ENERGY] - (0.5 * v**2 + 2.0 * s**2))) < 10 * tolerance


def test_invalid_parameters_are_rejected_at_initialization(fmus: dict[tuple[str, str], Path]) -> None:
    with pytest.raises(Exception, match="fmi2ExitInitializationMode failed with status 3"):
        simulate_fmu(str(fmus["2.0", "cs"]), stop_time=0.1, start_values={"spring.c": 0.0})
