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
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

from bridge.errors import ConfigError, DependencyMissing
from bridge.experiment.config import Experiment

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
    function: Callable[[T], R],
    items: Sequence[T],
    *,
    address: str | None = None,
    retries: int = RETRIES,
    resources: Mapping[str, float] | None = None,
) -> list[R]:
    """``[function(item) for item in items]``, each call a Ray task (1 CPU and ``resources``, e.g. a
    licence's seats; retried ``retries`` times when its worker or node dies); results in the order
    of ``items``. Resources no host of the cluster offers are refused, not left pending forever."""
    ray = connect(address)
    wanted = dict(resources or {})
    check_resources(ray, wanted)
    task = ray.remote(num_cpus=1, max_retries=retries, resources=wanted or None)(function)
    return list(ray.get([task.remote(item) for item in items]))


def licence_resources(experiment: Experiment, instances: int) -> dict[str, float]:
    """The custom resources a task that opens ``instances`` FMU instances asks for
    (``model.licence``; none without one)."""
    licence = experiment.model.licence
    if licence is None:
        return {}
    return {licence.resource: licence.per_instance * max(1, instances)}


def check_resources(ray: Any, wanted: Mapping[str, float]) -> None:
    """Refuse resources that no single host offers enough of (a task asking for them would wait
    for ever)."""
    if not wanted:
        return
    hosts = [node.get("Resources", {}) for node in ray.nodes() if node.get("Alive")]
    for name, amount in wanted.items():
        best = max((float(h.get(name, 0.0)) for h in hosts), default=0.0)
        if best < amount:
            raise ConfigError(
                f"the licence resource {name!r}: a task needs {amount:g} seats on one host, the most any "
                f"host of the cluster offers is {best:g}; start the licensed hosts with "
                f"ray start --resources '{{\"{name}\": SEATS}}' (SEATS >= {amount:g}), or lower n_envs"
            )


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
    resources: Mapping[str, float] | None = None,
) -> list[tuple[list[dict[str, Any]], list[Any], None]]:
    """Evaluation cells on Ray, chunk by chunk (each task with ``resources``); merged back to one
    (rows, traces) per cell with the episode numbers a single run gives."""
    chunks = chunked(cells, episodes_per_chunk)
    results = ray_map(run, [chunk for _, _, chunk in chunks], address=address, resources=resources)
    merged: list[tuple[list[dict[str, Any]], list[Any], None]] = [([], [], None) for _ in cells]
    for (index, start, _), (rows, traces, _recording) in zip(chunks, results):
        merged[index][0].extend({**row, "episode": start + int(row["episode"])} for row in rows)
        merged[index][1].extend(traces)
    return merged
