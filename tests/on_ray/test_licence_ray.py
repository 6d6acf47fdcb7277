"""Licence-aware placement on two Ray nodes on 127.0.0.1: an experiment's ``model.licence`` makes
every Ray task that opens its FMU take seats of a custom resource, so the work runs only on the host
that offers them (one seat: one task at a time) and gives the same report; a licence no host offers
is refused at once instead of waiting for ever."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")

from agents.evaluate import evaluate
from agents.ray_engine import ray_map
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment
from tests.on_ray.conftest import SEATS


def node_of_task() -> Any:
    """A task body that says on which node it ran (defined here: Ray ships it by value)."""

    def node_of(_: int) -> str:
        import ray

        return str(ray.get_runtime_context().get_node_id())

    return node_of


def licensed(tmp_path: Path, resource: str) -> Path:
    text = example_experiment("dcmotor_tracking").read_text()
    path = tmp_path / f"licensed_{resource}.yaml"
    path.write_text(text.replace("\nmodel:\n", f"\nmodel:\n  licence: {{resource: {resource}}}\n", 1))
    return path


def test_tasks_that_need_seats_run_only_where_the_seats_are(ray_cluster: Any, tmp_path: Path) -> None:
    import ray

    seated = [n["NodeID"] for n in ray.nodes() if n["Alive"] and n["Resources"].get(SEATS)]
    assert len(seated) == 1
    assert set(ray_map(node_of_task(), range(4), resources={SEATS: 1})) == set(seated)
    config = licensed(tmp_path, SEATS)
    assert "licence" in config.read_text()
    common: dict[str, Any] = {"episodes": 2, "seed": 5, "scenarios": ["step_up"]}
    remote = evaluate(["zero"], config, engine="ray", chunk_episodes=1, **common)
    local = evaluate(["zero"], config, **common)
    assert len(remote.rows) == 2
    for a, b in zip(remote.rows, local.rows):
        assert a.keys() == b.keys()
        assert all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in a)


def test_a_licence_no_host_offers_is_refused_not_left_pending(ray_cluster: Any, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"'no_such_seats'.*ray start --resources"):
        evaluate(["zero"], licensed(tmp_path, "no_such_seats"), engine="ray", episodes=1)
    with pytest.raises(ConfigError, match=rf"'{SEATS}': a task needs 2 seats"):
        ray_map(node_of_task(), [0], resources={SEATS: 2})
