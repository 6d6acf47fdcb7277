"""An env with MCAP recording vs the same env without, in one run (medians of interleaved repeats).

Run: python benchmarks/bench_record.py [--experiment NAME ...] [--steps N] [--repeats R]

Both envs are driven by the same balancing controller, so episodes run their full 500 samples
and resets (with their episode events and flushes) weigh the same. The recording env writes
all five streams of every step (observations, FMU inputs, raw action, reward, outputs) into a
zstd-compressed MCAP file in a temporary directory. Target: at least 0.7x the plain steps/s.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from common import interleaved, table

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from bridge.recording.env_recorder import RecordMcap
from bridge.recording.reader import read_recording

GAINS = (1.0, 1.5, 30.0, 5.0)  # a stabilising state feedback for the cart-pole


def loop(env: Any, discrete: bool) -> Any:
    def run(steps: int) -> None:
        _, info = env.reset(seed=0)
        y = info["outputs"].tolist()
        for _ in range(steps):
            force = max(-10.0, min(10.0, sum(g * v for g, v in zip(GAINS, y))))
            action = int(force > 0) if discrete else np.array([force / 10.0], dtype=np.float32)
            _, _, terminated, truncated, info = env.step(action)
            y = info["outputs"].tolist()
            if terminated or truncated:
                _, info = env.reset()
                y = info["outputs"].tolist()

    return run


def measure(name: str, steps: int, repeats: int, folder: Path) -> tuple[str, ...]:
    plain = FmuEnv(example_experiment(name))
    recorded = RecordMcap(FmuEnv(example_experiment(name)), folder / f"{name}.mcap")
    discrete = plain.action_space.shape == ()
    rates = interleaved(
        {"plain": loop(plain, discrete), "recorded": loop(recorded, discrete)}, steps, repeats
    )
    recorded.close()
    plain.close()
    path = recorded.path
    data = read_recording(path)
    messages = sum(data.message_counts.values())
    size = path.stat().st_size
    ratio = rates["recorded"] / rates["plain"]
    return (
        name,
        f"{rates['plain']:,.0f}",
        f"{rates['recorded']:,.0f}",
        f"{1e6 / rates['plain']:.2f}",
        f"{1e6 / rates['recorded']:.2f}",
        f"{ratio:.3f}",
        f"{messages:,}",
        f"{size / messages:.1f}",
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--experiment", nargs="+", default=["cartpole_balance", "cartpole_continuous"])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    print(f"{args.steps} steps x {args.repeats} repeats per env, interleaved; medians\n")
    with tempfile.TemporaryDirectory() as folder:
        rows = [measure(name, args.steps, args.repeats, Path(folder)) for name in args.experiment]
    header = (
        "experiment",
        "plain steps/s",
        "recorded steps/s",
        "plain us/step",
        "recorded us/step",
        "ratio",
        "messages",
        "bytes/message",
    )
    print(table(rows, header))
    print("\nratio = recorded / plain steps per second (target >= 0.7)")


if __name__ == "__main__":
    main()
