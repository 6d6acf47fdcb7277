"""A test run writes only to temporary folders: no tracked file under docs/ is rewritten unless asked."""

from __future__ import annotations

import os
from pathlib import Path

from tests.conftest import run_pytest
from tests.reliability_table import RUN_DIR, WRITE_DOCS, counts_dir

ROOT = Path(__file__).resolve().parents[1]


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p): (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*") if p.is_file()}


def test_the_counts_of_a_run_go_to_a_temporary_folder() -> None:
    if os.environ.get(WRITE_DOCS) == "1":
        return  # this run was asked to rewrite docs/reliability
    assert ROOT not in counts_dir().parents


def test_a_test_session_rewrites_nothing_under_docs(tmp_path: Path) -> None:
    """A whole pytest session, with its end-of-session hooks, in a subprocess."""
    before = _snapshot(ROOT / "docs")
    env = {k: v for k, v in os.environ.items() if k not in (WRITE_DOCS, RUN_DIR)}
    run = run_pytest(["tests/task/test_codegen.py"], tmp_path / "t", env, timeout_s=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert _snapshot(ROOT / "docs") == before
