"""Per-observation inference latency of a deployed policy: torch vs onnxruntime vs policy FMU.

    PYTHONPATH=$PWD python benchmarks/bench_deploy.py [RUN_DIR] [--n 5000]

Without RUN_DIR it trains a tiny PPO run (SB3's default 64x64 MlpPolicy, VecNormalize) on
examples/cartpole_continuous.yaml first. Each runtime answers the same observations one at a
time, the way a deployed agent calls it: torch through ``Sb3Policy.act`` (VecNormalize +
``model.predict``), onnxruntime through ``OnnxPolicy.act``, the policy FMU through FMPy
(set 4 inputs, get 1 output). One thread each.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def measure(act: Callable[[Any], Any], rows: np.ndarray, warm_up: int = 200) -> tuple[float, float]:
    for row in rows[:warm_up]:
        act(row)
    latencies = np.empty(len(rows))
    for k, row in enumerate(rows):
        start = time.perf_counter()
        act(row)
        latencies[k] = time.perf_counter() - start
    return float(np.median(latencies)) * 1e6, float(np.quantile(latencies, 0.99)) * 1e6


def tiny_run(root: Path) -> Path:
    from agents.train import train

    run = root / "ppo"
    overrides = {"algo": "PPO", "timesteps": 256, "n_envs": 1, "normalize": True}
    overrides["hyperparams"] = {"n_steps": 128, "batch_size": 64, "n_epochs": 1}
    train(Path("examples/cartpole_continuous.yaml"), overrides=overrides, run_dir=run, progress=False)
    return run


def main() -> None:
    import torch

    from agents.export.fmu_runner import FmuPolicy
    from agents.export.onnx import export_onnx
    from agents.export.policy_fmu import export_fmu
    from agents.policies import Sb3Policy
    from agents.runtime import OnnxPolicy

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", nargs="?", type=Path)
    parser.add_argument("--n", type=int, default=5000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        run = args.run or tiny_run(Path(tmp))
        policy, onnx_policy = Sb3Policy(run), OnnxPolicy(export_onnx(run, Path(tmp) / "p.onnx"))
        signals = np.random.default_rng(0).normal(0.0, [1.0, 1.5, 0.15, 1.5], size=(args.n, 4))
        obs = (signals / [2.4, 3.0, 0.20944, 3.0]).astype(np.float32)  # the experiment's scaling
        rows = {
            "torch (SB3 predict)": measure(lambda o: policy.act(o, {}), obs),
            "onnxruntime": measure(lambda o: onnx_policy.act(o, {}), obs),
        }
        with FmuPolicy(export_fmu(run, "2", Path(tmp) / "p.fmu")) as fmu:
            rows["policy FMU (FMI 2, via FMPy)"] = measure(fmu.act, signals)
    print(f"{'runtime':32s} {'median [us]':>12s} {'p99 [us]':>10s}   ({args.n} observations, one at a time)")
    for name, (median, p99) in rows.items():
        print(f"{name:32s} {median:12.1f} {p99:10.1f}")


if __name__ == "__main__":
    main()
