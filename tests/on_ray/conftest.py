"""Tests that need Ray (the ``ray`` extra, its own venv: ``.ci/ray``). Without Ray each module skips;
with ``FMU_BRIDGE_REQUIRE_RAY=1`` (set by ``.ci/ray``) a missing Ray fails the run instead.

``ray_cluster``: two Ray nodes on 127.0.0.1 in this machine (``ray.cluster_utils.Cluster``), one CPU
and a small object store each, the second with one seat of the licence resource ``SEATS``, in a
temporary folder of their own (``RAY_TMPDIR``): they never meet another Ray on this machine, and
shutting them down stops only them."""

from __future__ import annotations

import os
import shutil
import tempfile
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
    import ray
    from ray.cluster_utils import Cluster

    folder = tempfile.mkdtemp(prefix="fbray", dir="/tmp")  # short: Ray's socket paths must fit
    saved = {k: os.environ.get(k) for k in ("RAY_TMPDIR", "RAY_ADDRESS")}
    os.environ["RAY_TMPDIR"] = folder
    os.environ.pop("RAY_ADDRESS", None)
    node = {
        "num_cpus": 1,
        "object_store_memory": STORE,
        "node_ip_address": "127.0.0.1",
        "include_dashboard": False,
    }
    cluster = Cluster(initialize_head=True, connect=True, head_node_args=node)
    try:
        cluster.add_node(**node, resources={SEATS: 1})  # the only host with the licence's seats
        cluster.wait_for_nodes()
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        shutil.rmtree(folder, ignore_errors=True)
