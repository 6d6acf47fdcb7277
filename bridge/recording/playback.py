"""Play a recording back over Zenoh as if its node were running (``fmu-bridge replay --publish``).

The recorded ``/outputs`` become OUTPUTS frames (``bridge.net.protocol``) on
``<prefix>/<node>/outputs`` with their episode, step and simulation time, paced by the
recording clock (``rate`` 1: as recorded, 2: twice as fast, 0: as fast as possible). The
player also answers ``<prefix>/<node>/info`` and holds the node's liveliness token, so a
deployed agent that subscribes to a node's outputs can be tested against recorded data.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bridge.errors import BridgeError
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session
from bridge.recording import meta
from bridge.recording.export import episode_of, steps_of, timing
from bridge.recording.reader import Recording, read_recording

_log = logging.getLogger(__name__)


def node_description(recording: Recording, node: str) -> dict[str, Any]:
    """What the player answers on the info key: the recorded node's, or one built from the file."""
    run = recording.metadata.get("fmu_bridge", {})
    start_s, sampling_s = timing(recording)
    outputs = recording.series.get(meta.OUTPUTS)
    actions = recording.series.get(meta.ACTIONS)
    return {
        "node": node,
        "mode": "replay",
        "recording": str(recording.path),
        "experiment": run.get("experiment", ""),
        "version": run.get("version", ""),
        "fmu_sha256": run.get("fmu_sha256", ""),
        "sampling_time_s": sampling_s,
        "start_time_s": start_s,
        "output_names": outputs.names if outputs is not None else [],
        "input_names": actions.names if actions is not None else [],
    }


def publish(
    path: str | Path,
    *,
    node: str = "replay",
    options: ZenohOptions | None = None,
    session: Any = None,
    prefix: str = proto.DEFAULT_PREFIX,
    rate: float = 1.0,
    episode: int | None = None,
    stop: threading.Event | None = None,
    wait_s: float = 2.0,
) -> int:
    """Publish the recorded outputs as the node's frames; returns how many were sent.

    Args:
        wait_s: wait this long at most for a subscriber to the outputs before starting.
    """
    if rate < 0:
        raise BridgeError(f"--rate must be >= 0 (0: as fast as possible), got {rate}")
    recording = read_recording(path)
    outputs = recording.series.get(meta.OUTPUTS)
    if outputs is None or not len(outputs):
        raise BridgeError(f"{recording.path} has no {meta.OUTPUTS} messages to publish")
    episodes = episode_of(recording, outputs.log_ns)
    steps = steps_of(recording, outputs)
    rows = np.flatnonzero(episodes == episode) if episode is not None else np.arange(len(outputs))
    if not rows.size:
        raise BridgeError(f"--episode {episode}: no outputs recorded in it [{recording.path}]")
    keys = proto.Keys(prefix, node)
    own = session is None
    session = session if session is not None else open_session(options)
    description = proto.encode_json(node_description(recording, node))
    declared = [
        session.declare_queryable(
            keys.info, lambda query: query.reply(keys.info, description), complete=True
        ),
        session.liveliness().declare_token(keys.alive),
    ]
    publisher = session.declare_publisher(keys.outputs)
    declared.append(publisher)
    sent = 0
    try:
        _wait_for_subscriber(publisher, wait_s, stop)
        start_wall, start_log = time.monotonic(), int(outputs.log_ns[rows[0]])
        for row in rows:
            if rate > 0:
                due = start_wall + (int(outputs.log_ns[row]) - start_log) / 1e9 / rate
                if _sleep_until(due, stop):
                    break
            elif stop is not None and stop.is_set():
                break
            values = outputs.values[row]
            step, stamp = int(steps[row]), int(outputs.stamp_ns[row])
            publisher.put(proto.encode_values(proto.OUTPUTS, max(int(episodes[row]), 0), step, stamp, values))
            sent += 1
    finally:
        for entity in reversed(declared):
            entity.undeclare()
        if own:
            session.close()
    _log.info("published %d recorded frames as node %s", sent, keys.base)
    return sent


def _wait_for_subscriber(publisher: Any, wait_s: float, stop: threading.Event | None) -> None:
    deadline = time.monotonic() + wait_s
    while not publisher.matching_status.matching and time.monotonic() < deadline:
        if stop is not None and stop.is_set():
            return
        time.sleep(0.02)


def _sleep_until(due: float, stop: threading.Event | None) -> bool:
    """Wait until the monotonic time ``due``; True if ``stop`` was set meanwhile."""
    delay = due - time.monotonic()
    if stop is not None:
        return stop.wait(delay) if delay > 0 else stop.is_set()
    if delay > 0:
        time.sleep(delay)
    return False
