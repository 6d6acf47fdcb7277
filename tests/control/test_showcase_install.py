"""The showcase runs after the install line its page gives: the extras named there bring every
package the lqr and mpc baselines import, and its evaluation command runs as a user types it."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib.metadata import requires
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results.md"


def _showcase_block() -> str:
    text = RESULTS.read_text()
    start = text.index("fmu-bridge evaluate mpc lqr lqr_soft pid zero --config examples/vehicle_path.yaml")
    return text[text.rindex("```bash", 0, start) : text.index("```", start)]


def test_the_showcase_install_line_names_the_extras_its_baselines_need() -> None:
    block = _showcase_block()
    install = re.search(r'pip install -c constraints.txt -e "\.\[([a-z,]+)\]"', block)
    assert install, f"the showcase block has no install line:\n{block}"
    extras = set(install.group(1).split(","))
    brought = set()
    for requirement in requires("fmu-bridge") or []:  # the installed distribution's own metadata
        extra = re.search(r"extra == ['\"]([a-z]+)['\"]", requirement)
        if extra and extra.group(1) in extras:
            brought.add(re.split(r"[<>=;\[ ]", requirement, maxsplit=1)[0].lower())
    assert {"scipy", "osqp", "control", "stable-baselines3"} <= brought, sorted(brought)


@pytest.mark.integration
def test_the_showcase_evaluation_runs_as_typed(tmp_path: Path) -> None:
    """The page's command with one episode per scenario, run by the installed interpreter."""
    line = " ".join(
        part.rstrip("\\").strip()
        for part in _showcase_block().splitlines()
        if "fmu-bridge evaluate" in part or part.startswith("    --")
    )
    args = line.split()[1:]  # after "fmu-bridge"
    args = [a for a in args if a not in ("--workers", "2")]
    episodes = args.index("--episodes")
    args[episodes + 1] = "1"
    config = args.index("--config")
    args[config + 1] = str(ROOT / args[config + 1])
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", *args, "--out", str(tmp_path / "out")],
        capture_output=True, text=True, cwd=tmp_path, timeout=900, check=False,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "paired by seed: agent - mpc" in " ".join(result.stdout.split())
    assert (tmp_path / "out" / "report.md").is_file()
