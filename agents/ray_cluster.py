"""A Ray cluster of several nodes on this machine, on 127.0.0.1, that starts on a loaded machine
(needs ``fmu-bridge[ray]``): what the Ray tests and ``benchmarks/bench_ray.py`` run on.

Three things made a local cluster abort under load, and each has its answer here:

- **The startup waits.** The raylet gives the dashboard agent a fixed time to register
  (``RAY_agent_register_timeout_ms``, 30 s in Ray's source) and the driver gives the GCS a
  fixed time to publish its port; a loaded 2-core machine misses both. :data:`STARTUP_WAITS`
  raises them to minutes (set in this process's environment before a node starts, so its
  processes inherit them; values already set are kept).
- **Fixed ports.** Every node's agents listen on fixed default ports (the dashboard agent on
  52365), so two clusters on one machine (two test runs, a test run beside a benchmark) collide:
  each node gets free ports of its own (:func:`free_ports`).
- **A start can still fail** (a port taken between choosing and binding it): the whole cluster
  is torn down and started again, ``attempts`` times in all.

The cluster lives in a folder of its own (``RAY_TMPDIR``), so it never meets another Ray of the
user on this machine and its shutdown stops only it (never ``ray stop``).
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

_log = logging.getLogger(__name__)

#: Ray's startup waits (environment variables Ray reads), raised from seconds to minutes.
STARTUP_WAITS: Mapping[str, str] = {
    "RAY_agent_register_timeout_ms": "300000",
    "RAY_gcs_server_port_wait_time_s": "300",
}
_PORT_KEYS = ("dashboard_agent_listen_port", "metrics_export_port", "runtime_env_agent_port")


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports free on 127.0.0.1 now."""
    sockets = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            sockets.append(s)
        return [int(s.getsockname()[1]) for s in sockets]
    finally:
        for s in sockets:
            s.close()


def _node_args(node: Mapping[str, Any]) -> dict[str, Any]:
    ports = dict(zip(_PORT_KEYS, free_ports(len(_PORT_KEYS))))
    return {"node_ip_address": "127.0.0.1", "include_dashboard": False, **ports, **node}


@contextmanager
def local_cluster(
    nodes: Sequence[Mapping[str, Any]], *, attempts: int = 3, prefix: str = "fbray"
) -> Iterator[Any]:
    """A ``ray.cluster_utils.Cluster`` of ``nodes`` (each the keyword arguments of a node:
    ``num_cpus``, ``object_store_memory``, ``resources``), the first the head, this process
    connected to it; shut down (and its folder removed) on exit."""
    import ray
    from ray.cluster_utils import Cluster

    for key, value in STARTUP_WAITS.items():
        os.environ.setdefault(key, value)
    saved = {k: os.environ.get(k) for k in ("RAY_TMPDIR", "RAY_ADDRESS")}
    os.environ.pop("RAY_ADDRESS", None)
    cluster: Any = None
    folder = ""
    try:
        for attempt in range(1, attempts + 1):
            folder = tempfile.mkdtemp(prefix=prefix, dir="/tmp")  # short: socket paths must fit
            os.environ["RAY_TMPDIR"] = folder
            try:
                cluster = _start(Cluster, nodes)
                break
            except Exception as exc:  # Ray raises plain exceptions and TimeoutError on a failed start
                _log.warning("local Ray cluster: start %d of %d failed: %s", attempt, attempts, exc)
                ray.shutdown()
                shutil.rmtree(folder, ignore_errors=True)
                if attempt == attempts:
                    raise
        yield cluster
    finally:
        ray.shutdown()
        if cluster is not None:
            cluster.shutdown()
        shutil.rmtree(folder, ignore_errors=True)
        for key, before in saved.items():
            if before is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = before


def _start(cluster_class: Any, nodes: Sequence[Mapping[str, Any]]) -> Any:
    cluster = cluster_class(initialize_head=True, connect=True, head_node_args=_node_args(nodes[0]))
    try:
        for node in nodes[1:]:
            cluster.add_node(**_node_args(node))
        cluster.wait_for_nodes(timeout=300)
    except BaseException:
        cluster.shutdown()
        raise
    return cluster
