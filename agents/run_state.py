"""Whether a run's training is still alive: an OS lock held by the training process.

``train`` (and ``train --resume``) holds an exclusive ``flock`` on ``training.lock`` in the run
folder for as long as it trains. The kernel drops the lock when the process ends, however it ends
(SIGKILL, a crash, the machine's power), so a ``run.json`` that still says ``running`` while no
process holds the lock belongs to a training that ended without saying so: :func:`run_status`
reports it as ``interrupted``. A second ``train --resume`` on a run whose training is alive is
refused instead of racing it for the same files.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError

LOCK_NAME = "training.lock"
GONE = "its training process ended without finishing (killed or crashed)"


@contextlib.contextmanager
def training_lock(run_dir: Path) -> Iterator[None]:
    """Hold the run's training lock while the body runs; a ConfigError if a live process holds it."""
    path = run_dir / LOCK_NAME
    handle = path.open("a+")
    try:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "?"
            raise ConfigError(
                f"run {run_dir.name} is being trained by another process (pid {holder}); wait for it "
                f"to finish or stop it first [{run_dir}]"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield
    finally:
        handle.close()  # closing the file releases the lock


def training_alive(run_dir: Path) -> bool:
    """Whether a live process holds the run's training lock (no lock file: no such process)."""
    path = run_dir / LOCK_NAME
    try:
        handle = path.open("r")
    except FileNotFoundError:
        return False
    with handle:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
        return False


def run_status(run_dir: Path, info: dict[str, Any]) -> str:
    """The run's status: ``run.json``'s, except ``interrupted`` for a ``running`` (or ``starting``)
    run whose training process is gone."""
    status = str(info.get("status", ""))
    if status in ("running", "starting") and not training_alive(run_dir):
        return "interrupted"
    return status


def read_run(run_dir: Path) -> dict[str, Any]:
    """``run.json`` of ``run_dir`` ({} without one), its ``status`` as :func:`run_status` gives it;
    a run found dead gets ``status_detail`` saying so."""
    file = run_dir / "run.json"
    if not file.is_file():
        return {}
    info: dict[str, Any] = json.loads(file.read_text())
    status = run_status(run_dir, info)
    if status != info.get("status"):
        info["status"], info["status_detail"] = status, GONE
    return info
