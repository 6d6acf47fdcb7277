"""docs/reliability.md from the counts the fuzz and fault tests write as they run.

A test run writes only to temporary folders: the counts go to :func:`counts_dir` (a temporary
folder of the run) and, at the end of the session, ``conftest.py`` renders the table beside them.
The tracked files are rewritten only on request: with ``FMU_BRIDGE_WRITE_RELIABILITY=1`` the
counts go to ``docs/reliability/*.json`` and the table to ``docs/reliability.md``;
``python tests/reliability_table.py`` renders the table from the committed counts.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent.parent / "docs"
WRITE_DOCS = "FMU_BRIDGE_WRITE_RELIABILITY"  # "1": the run rewrites the tracked counts and table
RUN_DIR = "FMU_BRIDGE_RELIABILITY_DIR"  # the temporary folder of this run (shared with subprocesses)


def to_docs() -> bool:
    """Whether this run was asked to rewrite the tracked counts and table under docs/."""
    return os.environ.get(WRITE_DOCS) == "1"


def counts_dir() -> Path:
    """Where the fuzz and fault tests write their counts (docs/reliability/ only on request).

    Each test module keeps its tally in its process, so the tracked counts are rewritten only by a
    run in one process: under pytest-xdist two workers would each write a part of one module's."""
    if to_docs():
        if os.environ.get("PYTEST_XDIST_WORKER"):
            raise RuntimeError(
                f"{WRITE_DOCS}=1 under pytest-xdist: each worker would write a part of the counts; "
                "run it in one process (add -p no:xdist or -n 0)"
            )
        path = DOCS / "reliability"
    else:
        if not os.environ.get(RUN_DIR):
            os.environ[RUN_DIR] = tempfile.mkdtemp(prefix="fmu-bridge-reliability-")
        path = Path(os.environ[RUN_DIR])
    path.mkdir(parents=True, exist_ok=True)
    return path


def counts_file(name: str) -> Path:
    """The file a test module writes its counts ``name`` to: under pytest-xdist one per worker
    (each worker holds the tally of the tests it ran), read back together by :func:`read_counts`."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    stem = name.removesuffix(".json")
    return counts_dir() / (f"{stem}.{worker}.json" if worker else name)


def _merged(a: Any, b: Any) -> Any:
    """Two tallies as one: numbers added (a ``seed`` kept), mappings merged key by key, anything
    else kept."""
    if isinstance(a, dict) and isinstance(b, dict):
        both = {k: a[k] if k == "seed" else _merged(a[k], b[k]) for k in a.keys() & b.keys()}
        return {**a, **b, **both}
    if isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        return a + b
    return a


def read_counts(name: str) -> dict[str, Any] | None:
    """The counts ``name`` written in this run, the workers' parts added (None: none written)."""
    stem = name.removesuffix(".json")
    parts = [counts_dir() / name, *sorted(counts_dir().glob(f"{stem}.gw*.json"))]
    found = [json.loads(p.read_text()) for p in parts if p.is_file()]
    if not found:
        return None
    total = found[0]
    for part in found[1:]:
        total = _merged(total, part)
    return dict(total)


HEADER = """# Reliability: hostile input and faults, counted

Written by the test suite from `docs/reliability/*.json` (each fuzz or fault test writes its own
counts); regenerate with `FMU_BRIDGE_WRITE_RELIABILITY=1 pytest -q -m ""` (every tier: the node
fuzz and fault tests are integration tests; a plain test run writes its counts and this table to
a temporary folder) or `python tests/reliability_table.py`. Every row
asserts, in its test, that there were zero tracebacks, zero hangs and nothing silently wrong.

| test | what was thrown at it | outcome | tracebacks | hangs | silently wrong |
|---|---|---|---|---|---|
"""


def _experiments(data: dict[str, Any]) -> str:
    examples = data["examples"]
    mutations = sum(e["mutations"] for e in examples.values())
    rejected = sum(e["rejected_cleanly"] for e in examples.values())
    accepted = sum(e["accepted_and_sensible"] for e in examples.values())
    cli = sum(e["cli_check_runs"] for e in examples.values())
    tracebacks = sum(e["tracebacks"] for e in examples.values())
    return (
        f"| experiment files (`tests/experiment/test_fuzz.py`) | {mutations:,} seeded mutations of "
        f"{len(examples)} example files; {cli} through `fmu-bridge check` | {rejected:,} rejected with a "
        f"message naming the key, {accepted:,} accepted and sensible; `check` exits 0 or 2 | "
        f"{tracebacks} | 0 | 0 |"
    )


def _recordings(data: dict[str, Any]) -> str:
    return (
        f"| recordings (`tests/recording/test_recording_fuzz.py`) | a file cut at every one of "
        f"{data['cut_offsets']:,} byte offsets, {data['corruptions']:,} random corruptions "
        f"({', '.join(sorted(data['corruption_kinds']))}), {data['bombs']} decompression bombs, a full "
        f"disk; {data['reader_runs']:,} reader runs, {data['cli_runs']} CLI runs | "
        f"{data['clean_errors']} clear errors, {data['partial_reads']:,} partial reads, "
        f"{data['full_reads']} full; `recover` changed its input {data['inputs_changed_by_recover']} "
        f"times | {data['tracebacks']} | 0 | 0 |"
    )


def _nodes(data: dict[str, Any]) -> str:
    answered = data["info_ok"] + data["info_error_replies"] + data["reset_ok"] + data["reset_error_replies"]
    return (
        f"| nodes (`tests/net/test_node_fuzz.py`) | {data['requests']:,} malformed or random requests on "
        f"every key of a lockstep and a real-time node ({data['actions_sent']:,} actions, "
        f"{data['reset_sent']:,} resets, {data['info_sent']:,} info, {data['ros_reset_sent']} ROS resets, "
        f"{data['ros_actions_sent']} ROS actions) | {answered:,} queries answered, every action "
        f"accounted for ({data['actions_accounted_by_the_nodes']:,}); memory growth at most "
        f"{data['rss_growth_mb_max']:.0f} MB; afterwards a well-behaved client bit for bit: "
        f"{'yes' if data['well_behaved_client_bit_for_bit'] else 'NO'} | {data['tracebacks']} | "
        f"{data['hangs']} | {data['silently_wrong']} |"
    )


ROWS = {"experiment_fuzz.json": _experiments, "recording_fuzz.json": _recordings, "node_fuzz.json": _nodes}


def render() -> str:
    rows = []
    for name, row in ROWS.items():
        data = read_counts(name)
        if data is not None:
            rows.append(row(data))
    faults = (DOCS / "reliability" / "faults.md").read_text()  # the fault-injection table, by hand
    return HEADER + "\n".join(rows) + "\n\n" + faults


def write() -> Path:
    """The table, in docs/ on request, else beside this run's counts; the path written."""
    target = DOCS / "reliability.md" if to_docs() else counts_dir() / "reliability.md"
    target.write_text(render())
    return target


if __name__ == "__main__":
    os.environ[WRITE_DOCS] = "1"  # by hand: the table from the committed counts
    print(write())
