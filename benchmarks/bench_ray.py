"""RLlib over the batch env, side by side in one run (medians of interleaved repeats).

Needs the ``ray`` extra (its own venv: ``.venv-ray``). Rates are env steps per CPU second of this
process (``time.process_time``): one RLlib env runner lives in this process, so its CPU time is the
runner's, not diluted by other load on the machine.

Run: python benchmarks/bench_ray.py [--ks 1,8,64,256] [--steps 4096] [--repeats 3] [--no-cluster]
[--torch-threads 1]

Torch runs on one thread here (``--torch-threads``), as a runner given one CPU: with torch's default
thread pool the idle intra-op threads spin on a loaded machine and their CPU time, counted by
``process_time``, swamps both rates (3x lower) and makes their ratio noise.

1. One ``SingleAgentEnvRunner`` (RLlib's own, with its default PPO module choosing the actions)
   sampling from a NEXT_STEP ``BatchVectorEnv`` of K cart-pole FMUs, against the same runner over
   gymnasium's ``CartPole-v1`` vector env (SYNC) at the same K: RLlib's per-step cost is the floor
   there, so "batch / CartPole" says whether the FMU side is the bottleneck (target >= 0.8).
2. The batch env alone (random actions, NEXT_STEP) at the same K.
3. On a local two-node Ray cluster on 127.0.0.1 (one CPU each): time to the first sample of a PPO
   with one remote env runner over a batch env of 8, and the time from SIGKILL of that runner to
   its replacement serving a sample again (target <= 15 s).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # read when Ray is imported: keep 127.0.0.1
import signal
import statistics
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from common import table

from bridge.env.batch import BatchVectorEnv
from bridge.env.rllib import ppo_config
from bridge.experiment.examples import example_experiment


def runner_over(config: Any) -> Any:
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    return SingleAgentEnvRunner(config=config)


def cartpole_config(k: int) -> Any:
    from ray.rllib.algorithms.ppo import PPOConfig

    return PPOConfig().environment("CartPole-v1").env_runners(num_envs_per_env_runner=k)


def sampler(runner: Any) -> Callable[[int], None]:
    def run(steps: int) -> None:
        runner.sample(num_timesteps=steps, explore=True)

    return run


def batch_alone(k: int) -> Callable[[int], None]:
    env = BatchVectorEnv(example_experiment("cartpole_balance"), k, autoreset_mode="NextStep")
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def run(steps: int) -> None:
        for _ in range(max(1, steps // k)):
            env.step(rng.integers(0, 2, size=k))

    return run


def interleaved_cpu(named: dict[str, Callable[[int], None]], steps: int, repeats: int) -> dict[str, float]:
    for fn in named.values():
        fn(min(steps, 512))
    rates: dict[str, list[float]] = {name: [] for name in named}
    for _ in range(repeats):
        for name, fn in named.items():
            start = time.process_time()
            fn(steps)
            rates[name].append(steps / (time.process_time() - start))
    return {name: statistics.median(values) for name, values in rates.items()}


def rates(ks: list[int], steps: int, repeats: int) -> list[tuple[str, ...]]:
    rows = []
    experiment = example_experiment("cartpole_balance")
    for k in ks:
        n = max(steps, 4 * k)
        ours, theirs = runner_over(ppo_config(experiment, envs_per_runner=k)), runner_over(cartpole_config(k))
        got = interleaved_cpu(
            {"batch": sampler(ours), "cartpole": sampler(theirs), "alone": batch_alone(k)}, n, repeats
        )
        ours.stop()
        theirs.stop()
        row = (
            str(k),
            f"{got['batch']:,.0f}",
            f"{got['cartpole']:,.0f}",
            f"{got['batch'] / got['cartpole']:.2f}",
            f"{got['alone']:,.0f}",
        )
        print("K done:", " | ".join(row), flush=True)  # partial results on a slow machine
        rows.append(row)
    return rows


def cluster_times() -> list[tuple[str, str]]:
    from agents.ray_cluster import local_cluster

    node = {"num_cpus": 1, "object_store_memory": 80 * 2**20}
    with local_cluster([node, node], prefix="fbbench"):  # startup waits, free ports, retries
        config = ppo_config(example_experiment("cartpole_balance"), envs_per_runner=8, num_env_runners=1)
        config = config.fault_tolerance(
            restart_failed_env_runners=True, delay_between_env_runner_restarts_s=0.0
        )
        start = time.perf_counter()
        algo = config.build_algo()
        group = algo.env_runner_group
        group.foreach_env_runner(lambda r: r.sample(num_timesteps=64), local_env_runner=False)
        first = time.perf_counter() - start
        pid = group.foreach_env_runner(lambda r: os.getpid(), local_env_runner=False)[0]
        os.kill(pid, signal.SIGKILL)
        killed = time.perf_counter()
        while True:
            group.probe_unhealthy_env_runners()
            try:
                pids = group.foreach_env_runner(
                    lambda r: (r.sample(num_timesteps=64), os.getpid())[1], local_env_runner=False
                )
            except Exception:
                pids = []
            if pids and pid not in pids:
                break
            time.sleep(0.1)
        again = time.perf_counter() - killed
        algo.stop()
    return [
        ("time to first sample (build + 64 steps)", f"{first:.1f} s"),
        ("killed runner serving again", f"{again:.1f} s"),
    ]


def torch_threads() -> int:
    import torch

    return int(torch.get_num_threads())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--ks", default="1,8,64,256")
    parser.add_argument("--steps", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-cluster", action="store_true")
    parser.add_argument("--no-rates", action="store_true", help="only the cluster timings")
    parser.add_argument("--torch-threads", type=int, default=1, help="torch threads (0: its default)")
    args = parser.parse_args()
    if args.torch_threads > 0:
        import torch

        torch.set_num_threads(args.torch_threads)
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores", end="")
    print(f", torch threads {torch_threads()}\n")
    if not args.no_rates:
        rows = rates([int(k) for k in args.ks.split(",")], args.steps, args.repeats)
        header = ("K", "runner/batch env", "runner/CartPole-v1", "batch / CartPole", "batch env alone")
        print("env steps per CPU second of one RLlib env runner (medians)\n")
        print(table(rows, header))
    if not args.no_cluster:
        print()
        print(table(cluster_times(), ("two-node cluster on 127.0.0.1", "time")))


if __name__ == "__main__":
    gym.logger.min_level = 40
    main()
