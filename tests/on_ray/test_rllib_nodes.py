"""RLlib env runners that drive leased nodes (``training.vec: remote``): each runner hosts a NEXT_STEP
``NodeVectorEnv`` of K nodes (real ``fmu-bridge node`` subprocesses on a Zenoh router at 127.0.0.1)
that it leases from a pool. A node killed with SIGKILL is replaced by a spare and training goes on;
the Ray node hosting the runner removed and added again: Ray restarts the runner, which leases
nodes again (the dead runner's leases ended with its session), and training goes on."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

pytest.importorskip("ray.rllib")

from agents.rllib_train import build_config, train_rllib
from agents.settings import TrainingSettings
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, node_process
from tests.on_ray.conftest import SEATS, STORE

K = 2


def experiment(tmp_path: Path, net: Loopback, timesteps: int) -> Path:
    data = yaml.safe_load(example_experiment("cartpole_balance").read_text())
    data["node"] = {"prefix": net.prefix}
    data["training"] = {
        "algo": "PPO",
        "timesteps": timesteps,
        "n_envs": K,
        "seed": 2,
        "vec": "remote",
        "remote": {"nodes": "rl-*", "connect": [net.endpoint], "timeout_s": 15.0},  # live steps: well inside
        "hyperparams": {"n_steps": 32, "batch_size": 64, "n_epochs": 1, "policy_kwargs": {"net_arch": [16]}},
    }
    path = tmp_path / "cartpole_nodes.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@contextmanager
def pool(path: Path, net: Loopback, names: list[str]) -> Iterator[dict[str, Any]]:
    with ExitStack() as stack:
        yield {name: stack.enter_context(node_process(path, name, net)) for name in names}


def runner_state(algo: Any) -> list[dict[str, Any]]:
    def state(runner: Any) -> dict[str, Any]:
        import ray

        return {
            "pid": os.getpid(),
            "ray_node": ray.get_runtime_context().get_node_id(),
            "nodes": list(runner.env.unwrapped.node_names),
        }

    return list(algo.env_runner_group.foreach_env_runner(state, local_env_runner=False))


def test_a_runners_dead_zenoh_node_is_replaced_by_a_spare(
    ray_cluster: Any, loopback: Loopback, tmp_path: Path
) -> None:
    path = experiment(tmp_path, loopback, timesteps=320)
    seen: list[dict[str, Any]] = []
    with pool(path, loopback, ["rl-0", "rl-1", "rl-2"]) as processes:

        def on_iteration(algo: Any, result: dict[str, Any]) -> None:
            states = runner_state(algo)
            seen.append(
                {"states": states, "steps": int(result["env_runners"]["num_env_steps_sampled_lifetime"])}
            )
            if len(seen) == 1:
                victim = states[0]["nodes"][0]
                processes[victim].send_signal(signal.SIGKILL)
                processes[victim].wait(timeout=10)

        result = train_rllib(path, run_dir=tmp_path / "run", runners=1, on_iteration=on_iteration)
    first = seen[0]["states"][0]
    assert len(first["nodes"]) == K and len(set(first["nodes"])) == K
    spare = ({"rl-0", "rl-1", "rl-2"} - set(first["nodes"])).pop()
    last = seen[-1]["states"][0]
    assert last["pid"] == first["pid"], "the runner itself never died"
    assert last["nodes"] == [spare, first["nodes"][1]], seen  # the spare in the dead node's place
    assert result.timesteps >= 320 and seen[-1]["steps"] > seen[0]["steps"]
    assert (result.run_dir / "policy.onnx").is_file()


def test_the_ray_node_of_a_node_bound_runner_removed_and_added_again(
    ray_cluster: Any, loopback: Loopback, tmp_path: Path
) -> None:
    """The runner is placed on the worker Ray node (it asks for the seat only that node offers)."""
    path = experiment(tmp_path, loopback, timesteps=10_000)
    settings = TrainingSettings.from_experiment(load_experiment(path), {})
    config = build_config(path, settings, runners=1).env_runners(custom_resources_per_env_runner={SEATS: 1})
    with pool(path, loopback, ["rl-0", "rl-1"]):
        algo = config.build_algo()
        try:
            algo.train()
            before = runner_state(algo)
            worker = next(n for n in ray_cluster.list_all_nodes() if not n.head)
            assert [s["ray_node"] for s in before] == [worker.node_id]
            ray_cluster.remove_node(worker)
            ray_cluster.add_node(
                num_cpus=1,
                object_store_memory=STORE,
                node_ip_address="127.0.0.1",
                include_dashboard=False,
                resources={SEATS: 1},
            )
            ray_cluster.wait_for_nodes()
            deadline = time.monotonic() + 300
            after: list[dict[str, Any]] = []
            steps = []
            while time.monotonic() < deadline:
                result = algo.train()
                steps.append(int(result["env_runners"]["num_env_steps_sampled_lifetime"]))
                after = runner_state(algo)
                if (
                    after
                    and after[0]["pid"] != before[0]["pid"]
                    and len(steps) >= 2
                    and steps[-1] > steps[-2]
                ):
                    break
        finally:
            algo.stop()
    assert after and after[0]["pid"] != before[0]["pid"], f"no new runner: {before} {after}"
    assert after[0]["ray_node"] != worker.node_id  # on the node added again
    assert sorted(after[0]["nodes"]) == ["rl-0", "rl-1"]  # leased again: the old leases ended
    assert steps[-1] > steps[-2]  # and it samples
