"""The install is reproducible: constraints.txt pins every dependency the project names, and the
README's two commands and CI install through it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = Path(__file__).resolve().parents[1]


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~;\[ ]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def test_constraints_pin_every_dependency_of_every_extra() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = {_name(r) for r in project["dependencies"]}
    for extra in ("train", "viz", "dev", "docs"):
        wanted |= {_name(r) for r in project["optional-dependencies"][extra]}
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            spec = line.split(";")[0].strip()
            name, _, version = spec.partition("==")
            assert version and "+" not in version, f"constraints.txt: {line!r} is not an exact public pin"
            pins[name.lower().replace("_", "-")] = version
    assert wanted - set(pins) == set(), "not pinned in constraints.txt"
    assert "fmu-bridge" not in pins and "torch" in pins


def test_the_readme_commands_and_ci_install_through_the_constraints() -> None:
    readme = (ROOT / "README.md").read_text()
    commands = re.findall(r"```bash\n(python3 -m venv .*)\n```", readme)[:2]
    assert len(commands) == 2 and all("pip install -c constraints.txt -e" in c for c in commands), commands
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'pip install -q -c constraints.txt -e ".[train,viz,dev,docs]"' in ci
    assert "--upgrade-strategy eager" in ci  # and once more with the newest allowed versions
