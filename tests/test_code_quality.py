"""House rules enforced in CI: ruff (lint, format, import bans) and mypy --strict."""

from __future__ import annotations

import ast
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


_STATUS_NAMES = {"OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING", "STATUS_NAMES"}


def fmi_leaks(source: str) -> list[str]:
    """What in ``source`` belongs to ``bridge.fmu``: ctypes imports, and constants named like FMI
    statuses (``_WARNING = 1``, ``STATUS_NAMES = (...)``) holding FMI status values."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            modules = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            found += [f"line {node.lineno}: imports {m}" for m in modules if m.split(".")[0] == "ctypes"]
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant | ast.Tuple):
            names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            if any(n.lstrip("_").upper() == n.lstrip("_") and n.lstrip("_") in _STATUS_NAMES for n in names):
                values = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
                if all(isinstance(v, ast.Constant) and v.value in (0, 1, 2, 3, 4, 5) for v in values) or (
                    "STATUS_NAMES" in names
                ):
                    found.append(f"line {node.lineno}: defines {', '.join(names)}")
    return found


def test_the_fmi_leak_check_catches_ctypes_and_status_codes() -> None:
    assert fmi_leaks("import ctypes\nfrom ctypes import c_int\n_WARNING = 1\n") == [
        "line 1: imports ctypes",
        "line 2: imports ctypes",
        "line 3: defines _WARNING",
    ]
    assert fmi_leaks("import logging\nlevel = logging.WARNING\nTERMINATED = 1 << 0\n") == []


def test_only_bridge_fmu_speaks_ctypes_and_fmi_statuses() -> None:
    """bridge.fmu owns every FMU call: above it, outcomes are booleans and exceptions (the
    import contract in pyproject.toml says the same for lint-imports)."""
    leaks = {
        str(path.relative_to(ROOT)): found
        for package in ("bridge", "agents")
        for path in sorted((ROOT / package).rglob("*.py"))
        if "fmu" not in path.relative_to(ROOT / package).parts[:1] or package == "agents"
        if (found := fmi_leaks(path.read_text()))
    }
    assert leaks == {}, f"move these into bridge/fmu (abi.py holds the status codes): {leaks}"


def test_no_import_circles_closed_at_call_time() -> None:
    """An import inside a function that only breaks a circle hides a tangle: modules import each
    other one way (grimp reads function-level imports too; TYPE_CHECKING ones excluded), in
    ``bridge``, in ``agents`` and between them."""
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("bridge", "agents", exclude_type_checking_imports=True)
    circles = set()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            if module < imported and graph.find_shortest_chain(imported=module, importer=imported):
                circles.add((module, imported))
    assert circles == set(), "modules that import each other (through a chain)"
