"""House rules enforced in CI: ruff (lint, format, import bans) and mypy --strict."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ["bridge", "agents", "tests", "benchmarks", "launch_scripts"]


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)


def _tool(name: str) -> str:
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (pip install -e '.[dev]')")
    return found


def test_ruff_lint_and_import_rules() -> None:
    result = _run(_tool("ruff"), "check", *[p for p in PACKAGES if (ROOT / p).exists()])
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format() -> None:
    result = _run(_tool("ruff"), "format", "--check", *[p for p in PACKAGES if (ROOT / p).exists()])
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.slow
def test_mypy_strict() -> None:
    result = _run(_tool("mypy"))
    assert result.returncode == 0, result.stdout + result.stderr


def test_import_contracts_hold() -> None:
    """Layers and bans from pyproject.toml's [tool.importlinter] (import-linter)."""
    result = _run(_tool("lint-imports"))
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_task_the_remote_env_and_the_deployed_agent_never_load_fmpy() -> None:
    code = (
        "import sys, bridge.task, bridge.env, bridge.net.remote, bridge.net.protocol, agents.deploy; "
        "print(sorted(m for m in sys.modules if m == 'fmpy' or m.startswith('fmpy.')))"
    )
    result = _run(sys.executable, "-c", code)
    assert result.stdout.strip() == "[]", result.stdout + result.stderr


def test_bridge_never_imports_torch_sb3_or_agents() -> None:
    code = (
        "import sys, bridge, bridge.env.fmu_env, bridge.cli.main, bridge.fmu, bridge.task.core; "
        "bad = [m for m in ('torch', 'stable_baselines3', 'agents', 'rclpy', 'rerun') if m in sys.modules]; "
        "print(bad)"
    )
    result = _run(sys.executable, "-c", code)
    assert result.stdout.strip() == "[]", result.stdout + result.stderr
