"""PPO timesteps/s on the cart-pole FMU env vs gymnasium's CartPole-v1, identical hyperparameters.

Run: python benchmarks/bench_train.py [--timesteps N] [--repeats R] [--torch-threads default,chosen,2]

``--torch-threads`` compares torch thread counts on the FMU env instead: ``default`` (torch's own,
one per core), ``chosen`` (what ``train`` picks for the policy's size: ``agents.threads``) or a
number, each measured in alternation, with the load average at the start.

Both sides use the same PPO settings (RL Zoo's CartPole-v1 set, 8 envs in a DummyVecEnv, CPU),
measured in alternation; the ratio says whether the FMU env is the bottleneck of training.
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
from common import table
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment

HYPERPARAMS = {
    "n_steps": 32,
    "batch_size": 256,
    "gae_lambda": 0.8,
    "gamma": 0.98,
    "n_epochs": 20,
    "ent_coef": 0.0,
    "learning_rate": 0.001,
    "clip_range": 0.2,
}


def rate(make_env: object, timesteps: int) -> float:
    vec = make_vec_env(make_env, n_envs=8, seed=0)  # type: ignore[arg-type]
    model = PPO("MlpPolicy", vec, seed=0, device="cpu", verbose=0, **HYPERPARAMS)
    model.learn(total_timesteps=2048)  # warm-up: allocations, first compilation of torch kernels
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps, reset_num_timesteps=False)
    elapsed = time.perf_counter() - start
    vec.close()
    return timesteps / elapsed


def thread_rates(path: str, choices: list[str], timesteps: int, repeats: int) -> None:
    """PPO timesteps/s on the FMU env for each torch thread choice, measured in alternation."""
    import os

    import torch

    from agents.threads import threads_for, usable_cpus

    default = torch.get_num_threads()
    policy = PPO("MlpPolicy", gym.make("CartPole-v1"), device="cpu").policy
    params = sum(p.numel() for p in policy.parameters())
    counts = {
        c: default if c == "default" else threads_for(params, usable_cpus()) if c == "chosen" else int(c)
        for c in choices
    }
    load = os.getloadavg()
    rates: dict[str, list[float]] = {c: [] for c in choices}
    for _ in range(repeats):
        for choice, threads in counts.items():
            torch.set_num_threads(threads)
            rates[choice].append(rate(lambda: FmuEnv(path), timesteps))
    print(f"PPO MlpPolicy ({params:,} parameters), 8 envs, {timesteps} timesteps x {repeats} repeats")
    print(f"load average {load[0]:.1f} on {os.cpu_count()} cores\n")
    rows = [(f"{c} ({counts[c]})", f"{statistics.median(r):,.0f}") for c, r in rates.items()]
    print(table(rows, ("torch threads", "PPO timesteps/s (median)")))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--torch-threads", default=None, help="e.g. default,chosen,2")
    args = parser.parse_args()
    path = str(example_experiment("cartpole_balance"))
    if args.torch_threads:
        thread_rates(path, args.torch_threads.split(","), args.timesteps, args.repeats)
        return
    candidates = {
        "gymnasium CartPole-v1": lambda: gym.make("CartPole-v1"),
        "FmuEnv cart-pole FMU": lambda: FmuEnv(path),
    }
    rates: dict[str, list[float]] = {name: [] for name in candidates}
    for _ in range(args.repeats):
        for name, make in candidates.items():
            rates[name].append(rate(make, args.timesteps))
    medians = {name: statistics.median(values) for name, values in rates.items()}
    print(f"PPO, 8 envs, {args.timesteps} timesteps x {args.repeats} repeats, interleaved\n")
    print(table([(n, f"{r:,.0f}") for n, r in medians.items()], ("env", "PPO timesteps/s (median)")))
    ratio = medians["FmuEnv cart-pole FMU"] / medians["gymnasium CartPole-v1"]
    print(f"\nratio FMU env / CartPole-v1: {ratio:.3f}  (target >= 0.9)")


if __name__ == "__main__":
    main()
