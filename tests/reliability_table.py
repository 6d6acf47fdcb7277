"""docs/reliability.md from the counts the fuzz and fault tests write, committed only on request.

The tests write their counts as they run into a temporary folder (``FMU_BRIDGE_RELIABILITY_DIR``,
which ``conftest.py`` sets to a fresh one per test session unless given); at the end of the session
``write()`` renders ``reliability.md`` there, next to the counts, and the repository is left alone.
``python tests/reliability_table.py --commit FOLDER`` copies a run's counts into docs/reliability/
and regenerates docs/reliability.md: the step a maintainer takes on purpose.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent.parent / "docs"
COUNTS_ENV = "FMU_BRIDGE_RELIABILITY_DIR"


def counts_dir() -> Path:
    """Where this run's counts go: FMU_BRIDGE_RELIABILITY_DIR, or a fresh temporary folder."""
    folder = os.environ.get(COUNTS_ENV)
    if not folder:
        folder = os.environ[COUNTS_ENV] = tempfile.mkdtemp(prefix="fmu-bridge-reliability-")
    path = Path(folder)
    path.mkdir(parents=True, exist_ok=True)
    return path


def counts_path(name: str) -> Path:
    """The file a fuzz or fault test writes its counts to (in :func:`counts_dir`)."""
    return counts_dir() / name


HEADER = """# Reliability: hostile input and faults, counted

Who is trusted on which set-up (loopback by default, the network only when asked, admitted
clients with authentication) is in [zenoh.md](zenoh.md#who-is-trusted-on-which-set-up): peers,
files (experiments, FMUs, recordings) and FMUs themselves are treated as hostile input.

The counts below come from the fuzz and fault tests. Each test run writes its counts to a
temporary folder (`FMU_BRIDGE_RELIABILITY_DIR`, printed at the end of `pytest`) with this table
beside them; `python tests/reliability_table.py --commit FOLDER` copies a run's counts here when a
maintainer asks for it. Every row asserts, in its test, that there were zero tracebacks, zero
hangs and nothing silently wrong.

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


def render(source: Path) -> str:
    """The document from the counts in ``source`` (each missing file: the committed counts)."""
    rows = []
    for name, row in ROWS.items():
        path = source / name if (source / name).is_file() else DOCS / "reliability" / name
        if path.is_file():
            rows.append(row(json.loads(path.read_text())))
    faults = (DOCS / "reliability" / "faults.md").read_text()  # the fault-injection table, by hand
    return HEADER + "\n".join(rows) + "\n\n" + faults


def write() -> Path | None:
    """reliability.md beside this run's counts (in the temporary folder); None without counts."""
    source = Path(os.environ.get(COUNTS_ENV, ""))
    if not os.environ.get(COUNTS_ENV) or not any((source / name).is_file() for name in ROWS):
        return None
    target = source / "reliability.md"
    target.write_text(render(source))
    return target


def commit(source: Path) -> None:
    """Copy the counts in ``source`` into docs/reliability/ and regenerate docs/reliability.md."""
    for name in ROWS:
        if (source / name).is_file():
            shutil.copyfile(source / name, DOCS / "reliability" / name)
    (DOCS / "reliability.md").write_text(render(DOCS / "reliability"))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--commit":
        commit(Path(sys.argv[2]))
    else:
        sys.exit("usage: python tests/reliability_table.py --commit FOLDER  (a test run's counts folder)")
