"""Start-up of the launch file's defaults under load: how long until the agent sees observations.

    PYTHONPATH=$PWD python benchmarks/bench_launch_start.py RUN_DIR [--runs 4] [--burners 4] [--watch 60]
        [--runtime torch|onnx|fmu]

Runs the two command lines of ``launch_scripts/fmu_agent.launch.py`` with its defaults (rclpy
backend, real-time node, torch agent, no router; the node's Zenoh peer on 127.0.0.1), ``--runs``
times, each in a fresh random ROS domain, with ``--burners`` CPU burners (busy loops, killed at the
end) beside them. A third, plain-rclpy participant (this process, nothing of fmu-bridge) counts
the node's outputs and the agent's actions. Per run: seconds from the agent's start to its
"Ctrl-C stops it", to the first output and the first action this participant saw, how many of
each within ``--watch`` seconds, and the load average. Needs the ``ros`` extra.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import random
import runpy
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def burn() -> None:
    while True:
        pass


class Counter:
    """Counts JointState messages on two topics with plain rclpy (any publisher, any QoS that matches
    a reliable depth-10 subscription)."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("launch_counter", context=self.context)
        self.first: dict[str, float] = {}
        self.count = {"outputs": 0, "actions": 0}
        for key in self.count:
            self.node.create_subscription(
                JointState, f"/plant/{key}", lambda _msg, key=key: self._seen(key), 10
            )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _seen(self, key: str) -> None:
        self.count[key] += 1
        self.first.setdefault(key, time.monotonic())

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def one_run(run_dir: Path, watch_s: float, runtime: str) -> dict[str, Any]:
    launch = ROOT / "launch_scripts" / "fmu_agent.launch.py"
    experiment = ROOT / "examples" / "cartpole_balance.yaml"
    lines = runpy.run_path(str(launch))["commands"](str(run_dir), str(experiment), runtime=runtime)
    node_line = [*lines["fmu_node"], "--listen", f"tcp/127.0.0.1:{free_port()}"]
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.SystemRandom().randint(101, 200))}
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", RMW_IMPLEMENTATION="rmw_fastrtps_cpp")
    os.environ.update(env)  # the counter joins the same domain
    counter = Counter()
    started = time.monotonic()
    out = subprocess.DEVNULL
    node = subprocess.Popen([sys.executable, "-m", "bridge.cli", *node_line], env=env, stdout=out, stderr=out)
    agent = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *lines["fmu_agent"]],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    said: list[str] = []
    ready: list[float] = []

    def read() -> None:
        assert agent.stdout is not None
        for line in agent.stdout:
            said.append(line)
            if "Ctrl-C stops it" in " ".join("".join(said).split()) and not ready:
                ready.append(time.monotonic())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    time.sleep(watch_s)  # a benchmark watches for a fixed time; tests wait on conditions
    load = os.getloadavg()[0]
    for process in (agent, node):
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    reader.join(5)
    counter.close()

    def since(t: float | None) -> str:
        return "-" if t is None else f"{t - started:.1f}"

    return {
        "ready_s": since(ready[0] if ready else None),
        "first_output_s": since(counter.first.get("outputs")),
        "first_action_s": since(counter.first.get("actions")),
        "outputs": counter.count["outputs"],
        "actions": counter.count["actions"],
        "load": f"{load:.1f}",
        "agent_said": "".join(said)[-600:],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--burners", type=int, default=4)
    parser.add_argument("--watch", type=float, default=60.0)
    parser.add_argument("--runtime", default="torch", help="the launch file's runtime: torch, onnx or fmu")
    parser.add_argument("--verbose", action="store_true", help="print the agent's last output lines")
    args = parser.parse_args()
    burners = [multiprocessing.Process(target=burn, daemon=True) for _ in range(args.burners)]
    for b in burners:
        b.start()
    try:
        print("| run | agent ready [s] | first output [s] | first action [s] | outputs | actions | load |")
        print("|---|---|---|---|---|---|---|")
        for k in range(args.runs):
            r = one_run(args.run_dir, args.watch, args.runtime)
            print(
                f"| {k + 1} | {r['ready_s']} | {r['first_output_s']} | {r['first_action_s']} | "
                f"{r['outputs']} | {r['actions']} | {r['load']} |",
                flush=True,
            )
            if args.verbose or r["actions"] == 0:
                print(r["agent_said"], flush=True)
    finally:
        for b in burners:
            b.terminate()
            b.join()


if __name__ == "__main__":
    main()
