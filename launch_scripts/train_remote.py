"""Start K FMU nodes on this machine and train PPO against them through RemoteVecEnv.

Run:  python launch_scripts/train_remote.py [--experiment examples/cartpole_balance.yaml]
          [--nodes 4] [--timesteps 50000] [--port 7447]

This process is the Zenoh router (127.0.0.1 only); every node is a subprocess connecting to
it, so `fmu-bridge nodes --connect tcp/127.0.0.1:PORT` lists them while training runs. For
nodes on other machines, see docs/zenoh.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from stable_baselines3 import PPO

from bridge.env import RemoteVecEnv
from bridge.net.transport import ZenohOptions, open_session

ROOT = Path(__file__).resolve().parent.parent


def start_nodes(experiment: Path, count: int, endpoint: str) -> list[subprocess.Popen[bytes]]:
    processes = []
    for i in range(count):
        cmd = [
            sys.executable,
            "-m",
            "bridge.cli",
            "node",
            str(experiment),
            "--name",
            f"worker-{i}",
            "--connect",
            endpoint,
        ]
        processes.append(subprocess.Popen(cmd, env={**os.environ, "PYTHONUNBUFFERED": "1"}))
    return processes


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--experiment", type=Path, default=ROOT / "examples" / "cartpole_balance.yaml")
    parser.add_argument("--nodes", type=int, default=4)
    parser.add_argument("--timesteps", type=int, default=50_000)
    parser.add_argument("--port", type=int, default=7447)
    parser.add_argument("--save", type=Path, default=Path("runs/remote_ppo.zip"))
    args = parser.parse_args()

    endpoint = f"tcp/127.0.0.1:{args.port}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    nodes = start_nodes(args.experiment, args.nodes, endpoint)
    try:
        vec = RemoteVecEnv(
            args.experiment, "worker-*", n_envs=args.nodes, session=session, discovery_timeout_s=60.0
        )
        model = PPO(
            "MlpPolicy",
            vec,
            n_steps=max(64, 2048 // args.nodes),
            batch_size=64,
            seed=0,
            device="cpu",
            verbose=1,
        )
        start = time.perf_counter()
        model.learn(total_timesteps=args.timesteps)
        elapsed = time.perf_counter() - start
        args.save.parent.mkdir(parents=True, exist_ok=True)
        model.save(args.save)
        print(
            f"trained {model.num_timesteps} steps on {args.nodes} nodes in {elapsed:.1f} s "
            f"({model.num_timesteps / elapsed:,.0f} steps/s); saved {args.save}"
        )
        vec.close()
    finally:
        for process in nodes:
            process.terminate()
        for process in nodes:
            process.wait(timeout=10)
        session.close()


if __name__ == "__main__":
    main()
