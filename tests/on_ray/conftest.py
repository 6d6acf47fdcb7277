"""Tests that need Ray (the ``ray`` extra, its own venv: ``.ci/ray``). Without Ray each module skips;
with ``FMU_BRIDGE_REQUIRE_RAY=1`` (set by ``.ci/ray``) a missing Ray fails the run instead.

``ray_cluster``: two Ray nodes on 127.0.0.1 in this machine (``ray.cluster_utils.Cluster``), one CPU
and a small object store each, the second with one seat of the licence resource ``SEATS``, in a
temporary folder of their own (``RAY_TMPDIR``): they never meet another Ray on this machine, and
shutting them down stops only them. ``agents.ray_cluster.local_cluster`` starts them: raised
startup waits, free ports per node and a retry, so they start on a loaded machine."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest

# Read when Ray is imported: keep a local cluster on 127.0.0.1, not on the host's address.
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"

if os.environ.get("FMU_BRIDGE_REQUIRE_RAY") == "1":
    import ray  # noqa: F401  (an ImportError here fails the run: these tests must run, not skip)

STORE = 80 * 2**20  # bytes of object store per node: small, the machine is shared
SEATS = "fmu_test_seats"  # a licence's custom resource: one seat, on the second node only


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[Any]:
    pytest.importorskip("ray")
    from agents.ray_cluster import local_cluster

    node = {"num_cpus": 1, "object_store_memory": STORE}
    # the second node is the only host with the licence's seats; startup waits, free ports and
    # retries for a loaded machine: agents/ray_cluster.py
    with local_cluster([node, {**node, "resources": {SEATS: 1}}]) as cluster:
        yield cluster
