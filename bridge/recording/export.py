"""Tables from a recording: episodes, per-stream columns, CSV/Parquet export, the info summary.

Every stream becomes one table with the time columns ``log_time_ns`` (the recording clock),
``time_s`` (the same in seconds), ``episode``, ``step`` (sample index within the episode,
from the stamp and the recorded timing) and ``sim_time_s`` (the header stamp), then one
column per signal name. Events become a table of their JSON fields.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import DependencyMissing
from bridge.recording.reader import Recording, Series


def episode_of(recording: Recording, log_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """The episode index of each log time (-1 before the first episode)."""
    found = recording.episodes
    if not found:
        return np.full(len(log_ns), -1, dtype=np.int64)
    starts = np.array([e.start_ns for e in found], dtype=np.int64)
    indices = np.array([e.index for e in found], dtype=np.int64)
    position = np.searchsorted(starts, log_ns, side="right") - 1
    return np.where(position >= 0, indices[np.maximum(position, 0)], -1)


def timing(recording: Recording) -> tuple[float, float]:
    """(start_time_s, sampling_time_s) of the recorded experiment (0, 0 if unknown)."""
    run = recording.metadata.get("fmu_bridge", {})
    try:
        start, sampling = float(run.get("start_time_s", 0.0)), float(run.get("sampling_time_s", 0.0))
    except ValueError:
        return 0.0, 0.0
    if not (math.isfinite(start) and math.isfinite(sampling) and sampling >= 0):
        return 0.0, 0.0
    return start, sampling


def steps_of(recording: Recording, series: Series) -> npt.NDArray[np.int64]:
    """Sample index of each message within its episode (-1 where unknown).

    On the recording clock an episode starts at its start event, and sample ``k`` lies ``k``
    sampling periods later, so the index follows from the log time alone (for every type).
    """
    _, sampling_s = timing(recording)
    found = recording.episodes
    if sampling_s <= 0 or not found:
        return np.full(len(series), -1, dtype=np.int64)
    starts = np.array([e.start_ns for e in found], dtype=np.int64)
    position = np.searchsorted(starts, series.log_ns, side="right") - 1
    since = series.log_ns - starts[np.maximum(position, 0)]
    steps = np.round(since / (sampling_s * 1e9)).astype(np.int64)
    return np.where(position >= 0, steps, -1)


def columns(recording: Recording, series: Series) -> dict[str, npt.NDArray[Any]]:
    """A stream as named columns (time columns first)."""
    table: dict[str, npt.NDArray[Any]] = {
        "log_time_ns": series.log_ns,
        "time_s": series.log_ns / 1e9,
        "episode": episode_of(recording, series.log_ns),
        "step": steps_of(recording, series),
    }
    if series.stamped:
        table["sim_time_s"] = series.stamp_ns / 1e9
    if series.texts:
        table["text"] = np.array(series.texts, dtype=object)
    elif series.values.ndim == 2:
        for i, name in enumerate(series.names):
            table[name] = series.values[:, i]
    elif series.values.size:
        table[series.names[0] if series.names else "value"] = series.values
    return table


def _file_name(topic: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", topic.strip("/")) or "root"


def export_csv(recording: Recording, directory: str | Path) -> list[Path]:
    """One CSV file per stream in ``directory``; returns the files written."""
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for topic, series in recording.series.items():
        table = columns(recording, series)
        path = folder / f"{_file_name(topic)}.csv"
        with path.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(list(table))
            for row in zip(*(_csv_cells(c) for c in table.values())):
                writer.writerow(row)
        written.append(path)
    return written


def _csv_cells(column: npt.NDArray[Any]) -> list[Any]:
    if column.dtype.kind == "f":
        return [repr(float(v)) for v in column]  # shortest text that reads back to the same float
    return column.tolist()  # type: ignore[no-any-return]


def export_parquet(recording: Recording, directory: str | Path) -> list[Path]:
    """One Parquet file per stream in ``directory`` (needs pyarrow)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise DependencyMissing("pyarrow", "Parquet export", "pip install pyarrow") from exc
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for topic, series in recording.series.items():
        table = columns(recording, series)
        arrays = {k: pa.array(v.tolist() if v.dtype == object else v) for k, v in table.items()}
        path = folder / f"{_file_name(topic)}.parquet"
        pq.write_table(pa.table(arrays), path)
        written.append(path)
    return written


def describe(recording: Recording) -> dict[str, Any]:
    """What ``fmu-bridge info`` shows, as plain data."""
    all_times = [s.log_ns for s in recording.series.values() if len(s)]
    start = int(min(t.min() for t in all_times)) if all_times else 0
    end = int(max(t.max() for t in all_times)) if all_times else 0
    return {
        "path": str(recording.path),
        "complete": recording.complete,
        "problems": recording.problems,
        "profile": recording.profile,
        "library": recording.library,
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) / 1e9,
        "channels": [
            {"topic": t, "type": s.msgtype, "messages": len(s), "names": s.names}
            for t, s in recording.series.items()
        ],
        "episodes": [dataclasses.asdict(e) for e in recording.episodes],
        "metadata": recording.metadata,
        "attachments": [
            {"name": a.name, "media_type": a.media_type, "bytes": len(a.data)} for a in recording.attachments
        ],
    }
