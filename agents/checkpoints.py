"""Checkpoints that a kill cannot cut, and the newest loadable one to resume from.

A file is written beside its final name and renamed over it (``os.replace``, atomic on POSIX),
so a run killed while saving leaves the previous file whole; a resumed run still tries its
candidates newest first and skips any that does not load (a file cut by an older version, a full
disk), saying which.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.errors import ConfigError

_log = logging.getLogger(__name__)
_STEPS = re.compile(r"_(\d+)_steps\.zip$")


def save_atomically(write: Callable[[Path], Any], path: Path) -> None:
    """``write`` the file to a temporary name beside ``path``, then rename it to ``path``; on any
    failure the temporary file is removed and ``path`` keeps what it had."""
    temporary = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        write(temporary)
        with open(temporary, "rb") as written:
            os.fsync(written.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def write_run_info(run_dir: Path, info: dict[str, Any]) -> None:
    """``run.json``, written atomically: a reader (``compare``, a monitor) never sees half of it."""
    save_atomically(lambda path: path.write_text(json.dumps(info, indent=2)), run_dir / "run.json")


def atomic_checkpoints(save_freq: int, folder: Path, *, save_vecnormalize: bool) -> Any:
    """SB3's CheckpointCallback (same names: ``rl_model_<steps>_steps.zip``), each file written
    atomically, the VecNormalize statistics before the model they belong to."""
    from stable_baselines3.common.callbacks import CheckpointCallback

    class AtomicCheckpoints(CheckpointCallback):
        def _on_step(self) -> bool:
            if self.n_calls % self.save_freq == 0:
                stats = self.model.get_vec_normalize_env()
                if self.save_vecnormalize and stats is not None:
                    target = Path(self._checkpoint_path("vecnormalize_", extension="pkl"))
                    save_atomically(lambda path: stats.save(str(path)), target)
                save_atomically(self.model.save, Path(self._checkpoint_path(extension="zip")))
            return True

    return AtomicCheckpoints(save_freq, str(folder), save_vecnormalize=save_vecnormalize)


def resume_candidates(run_dir: Path) -> list[tuple[Path, Path | None]]:
    """What a resumed run may continue from, newest first: ``model.zip`` (with
    ``vecnormalize.pkl``), then each checkpoint (with its statistics)."""
    found: list[tuple[Path, Path | None]] = []
    if (run_dir / "model.zip").is_file():
        stats = run_dir / "vecnormalize.pkl"
        found.append((run_dir / "model.zip", stats if stats.is_file() else None))
    saved = sorted(
        ((int(m.group(1)), p) for p in (run_dir / "checkpoints").glob("*_steps.zip")
         if (m := _STEPS.search(p.name)) and "vecnormalize" not in p.name),
        reverse=True,
    )  # fmt: skip
    for steps, model in saved:
        stats = model.with_name(model.name.replace(f"_{steps}_steps.zip", f"_vecnormalize_{steps}_steps.pkl"))
        found.append((model, stats if stats.is_file() else None))
    return found


def load_newest(
    run_dir: Path, load: Callable[[Path], Any], candidates: list[tuple[Path, Path | None]]
) -> tuple[Any, Path, Path | None]:
    """The newest candidate that loads: (model, its file, its statistics); ConfigError naming
    every file tried and why when none does."""
    if not candidates:
        raise ConfigError(
            f"--resume {run_dir}: the run has no model.zip and no checkpoint to continue from "
            "(its training ended before the first checkpoint); train it again"
        )
    failures = []
    for model_file, stats in candidates:
        try:
            model = load(model_file)
        except Exception as exc:  # a cut or empty file: SB3 raises ValueError, zipfile BadZipFile, ...
            failures.append(f"{model_file.relative_to(run_dir)}: {str(exc)[:200]}")
            _log.warning(
                "run %s: %s does not load (%s); trying an older one", run_dir.name, model_file.name, exc
            )
            continue
        steps = _STEPS.search(model_file.name)
        if steps is not None:
            _log.warning(
                "run %s has no loadable model.zip: resuming from its checkpoint at %s steps",
                run_dir.name, f"{int(steps.group(1)):,}",
            )  # fmt: skip
        return model, model_file, stats
    raise ConfigError(
        f"--resume {run_dir}: no saved model loads; tried, newest first: {'; '.join(failures)}; "
        "train the run again"
    )
