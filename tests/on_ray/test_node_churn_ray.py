"""A Ray node removed and added again: the evaluation grid runs on what is left, then again on both
nodes once the node is back (the licence seat with it), and equals the single-machine run each time."""

from __future__ import annotations

import math
from typing import Any

import pytest

pytest.importorskip("ray")

from agents.evaluate import evaluate
from bridge.experiment.examples import example_experiment
from tests.on_ray.conftest import SEATS, STORE


def same_rows(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> bool:
    return len(a) == len(b) and all(
        x.keys() == y.keys()
        and all(
            x[k] == y[k] or (isinstance(x[k], float) and math.isnan(x[k]) and math.isnan(y[k])) for k in x
        )
        for x, y in zip(a, b)
    )


def alive() -> list[dict[str, Any]]:
    import ray

    return [n for n in ray.nodes() if n["Alive"]]


def test_a_node_removed_and_added_again(ray_cluster: Any) -> None:
    config = example_experiment("dcmotor_tracking")
    common: dict[str, Any] = {"episodes": 2, "seed": 7, "scenarios": ["step_up"]}
    local = evaluate(["zero", "pid"], config, **common)
    worker = next(n for n in ray_cluster.list_all_nodes() if not n.head)
    ray_cluster.remove_node(worker)
    ray_cluster.wait_for_nodes()
    assert len(ray_cluster.list_all_nodes()) == 1
    alone = evaluate(["zero", "pid"], config, engine="ray", chunk_episodes=1, **common)
    assert same_rows(alone.rows, local.rows)
    ray_cluster.add_node(
        num_cpus=1,
        object_store_memory=STORE,
        node_ip_address="127.0.0.1",
        include_dashboard=False,
        resources={SEATS: 1},
    )
    ray_cluster.wait_for_nodes()
    assert [n["Resources"].get(SEATS) for n in alive()].count(1.0) == 1  # the seat is back
    both = evaluate(["zero", "pid"], config, engine="ray", chunk_episodes=1, **common)
    assert same_rows(both.rows, local.rows)
