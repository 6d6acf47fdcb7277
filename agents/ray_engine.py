"""Ray as an engine for the grids that already run on one machine (needs ``fmu-bridge[ray]``).

The work is cut into the same units the single-machine code runs: an evaluation cell (agent x
scenario) split into chunks of episodes, a training run per seed and hyperparameter set. Each unit
is a Ray task that calls the single-machine function unchanged (``run_cell``, ``train``), so a
result from Ray is the result of the same seeds on one machine; Ray retries a task whose worker or
node died (``max_retries``), and the results are merged in grid order into the usual report.

Ray has no authentication: connect only to clusters on networks you trust (docs/ray.md).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from bridge.errors import ConfigError, DependencyMissing

T = TypeVar("T")
R = TypeVar("R")
RETRIES = 3


def connect(address: str | None = None) -> Any:
    """The ``ray`` module, connected: to ``address`` (``ray://`` or ``host:port``; ``auto``: the
    cluster of ``ray start`` on this host; default ``$RAY_ADDRESS``, else a local Ray of this
    process); an already connected Ray is kept."""
    try:
        import ray
    except ImportError as exc:
        raise DependencyMissing(
            "ray", "the Ray engine", 'pip install "fmu-bridge[ray]" (a venv of its own: Ray pins gymnasium)'
        ) from exc
    if not ray.is_initialized():
        address = address or os.environ.get("RAY_ADDRESS")
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    return ray


def ray_map(
    function: Callable[[T], R], items: Sequence[T], *, address: str | None = None, retries: int = RETRIES
) -> list[R]:
    """``[function(item) for item in items]``, each call a Ray task (1 CPU, retried ``retries``
    times when its worker or node dies); results in the order of ``items``."""
    ray = connect(address)
    task = ray.remote(num_cpus=1, max_retries=retries)(function)
    return list(ray.get([task.remote(item) for item in items]))


def chunked(cells: Sequence[Any], episodes_per_chunk: int) -> list[tuple[int, int, Any]]:
    """Evaluation cells cut into chunks of at most ``episodes_per_chunk`` seeds:
    ``(cell index, first episode, chunk cell)`` in grid order."""
    if episodes_per_chunk < 1:
        raise ConfigError(f"episodes per chunk must be at least 1, got {episodes_per_chunk}")
    chunks = []
    for index, cell in enumerate(cells):
        for start in range(0, len(cell.seeds), episodes_per_chunk):
            seeds = cell.seeds[start : start + episodes_per_chunk]
            chunks.append((index, start, dataclasses.replace(cell, seeds=seeds)))
    return chunks


def map_cells(
    run: Callable[[Any], tuple[list[dict[str, Any]], list[Any], Any]],
    cells: Sequence[Any],
    *,
    episodes_per_chunk: int,
    address: str | None = None,
) -> list[tuple[list[dict[str, Any]], list[Any], None]]:
    """Evaluation cells on Ray, chunk by chunk; merged back to one (rows, traces) per cell with the
    episode numbers a single run gives."""
    chunks = chunked(cells, episodes_per_chunk)
    results = ray_map(run, [chunk for _, _, chunk in chunks], address=address)
    merged: list[tuple[list[dict[str, Any]], list[Any], None]] = [([], [], None) for _ in cells]
    for (index, start, _), (rows, traces, _recording) in zip(chunks, results):
        merged[index][0].extend({**row, "episode": start + int(row["episode"])} for row in rows)
        merged[index][1].extend(traces)
    return merged
