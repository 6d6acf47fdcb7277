"""Remote vs local stepping on loopback, in one run: latency per sample and vector throughput.

Run: python benchmarks/bench_remote.py [--steps N] [--nodes 1,2,4]

Prints the per-sample latency (median, p99) of RemoteFmuEnv, of the in-process FmuEnv and of a
bare Zenoh ping-pong between two processes with the same payload size and the same wake-up
mechanism (callback + event), then RemoteVecEnv throughput with 1, 2 and 4 nodes.

Beside the latency, the CPU time one RemoteFmuEnv step costs, in the client process and in the
node's process (every thread, from /proc/<pid>/task/*/schedstat; Linux only), and how often
their threads were scheduled: on a loaded machine wall-clock medians are mostly the wait for a
core, while CPU time and wake-ups still say what the step itself costs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from common import table

from bridge.env import RemoteFmuEnv, RemoteVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session

ECHO = """
import sys, threading, zenoh
zenoh.init_log_from_env_or("error")
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", '["{endpoint}"]')
conf.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(conf)
pub = s.declare_publisher("bench/pong")
sub = s.declare_subscriber("bench/ping", lambda sample: pub.put(sample.payload.to_bytes()))
s.liveliness().declare_token("bench/echo")
print("ready", flush=True)
threading.Event().wait()
"""


def percentiles(samples: list[float]) -> tuple[float, float]:
    ordered = sorted(samples)
    return statistics.median(ordered) * 1e6, ordered[int(0.99 * (len(ordered) - 1))] * 1e6


def start(cmd: list[str], ready: str) -> subprocess.Popen[str]:
    process = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert process.stdout is not None
    deadline = time.monotonic() + 60
    for line in process.stdout:
        if ready in line:
            return process
        if time.monotonic() > deadline:
            break
    process.kill()
    raise RuntimeError(f"{cmd} did not start")


def start_node(experiment: Path, name: str, endpoint: str) -> subprocess.Popen[str]:
    return start(
        [sys.executable, "-m", "bridge.cli", "node", str(experiment), "--name", name, "--connect", endpoint],
        "serving",
    )


def ping_pong(session: object, payload_size: int, steps: int) -> list[float]:
    event, samples = threading.Event(), []
    sub = session.declare_subscriber("bench/pong", lambda s: event.set())  # type: ignore[attr-defined]
    pub = session.declare_publisher("bench/ping")  # type: ignore[attr-defined]
    payload = bytes(payload_size)
    for _ in range(200):
        event.clear()
        pub.put(payload)
        event.wait(2.0)
    for _ in range(steps):
        event.clear()
        t = time.perf_counter()
        pub.put(payload)
        if not event.wait(2.0):
            raise RuntimeError("echo lost")
        samples.append(time.perf_counter() - t)
    sub.undeclare()
    pub.undeclare()
    return samples


def cpu_ns(pid: int) -> tuple[int, int]:
    """CPU time (ns) and time slices so far of every thread of process ``pid`` ((0, 0) where
    /proc has no schedstat)."""
    run = slices = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        try:
            fields = stat.read_text().split()
        except OSError:  # the thread ended meanwhile
            continue
        run, slices = run + int(fields[0]), slices + int(fields[2])
    return run, slices


def env_latency(env: object, steps: int, cpu: dict[str, int] | None = None) -> list[float]:
    """Step latencies; with ``cpu`` (``{"client": pid, "node": pid}``), each process's CPU time
    and time slices over the steps are written back into it as ``<who>_ns``/``<who>_slices``."""
    action = np.zeros(1, dtype=np.float32)
    env.reset(seed=0)  # type: ignore[attr-defined]
    samples = []
    before = {who: cpu_ns(pid) for who, pid in (cpu or {}).items()}
    for _ in range(steps):
        t = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)  # type: ignore[attr-defined]
        samples.append(time.perf_counter() - t)
        if terminated or truncated:
            env.reset()  # type: ignore[attr-defined]
    for who, (run, slices) in before.items():
        now = cpu_ns(cpu[who]) if cpu else (0, 0)
        cpu[who + "_ns"], cpu[who + "_slices"] = now[0] - run, now[1] - slices  # type: ignore[index]
    env.close()  # type: ignore[attr-defined]  # ends its lease on the node: the vector env uses it next
    return samples


def vec_throughput(experiment: Path, names: list[str], session: object, steps: int) -> float:
    vec = RemoteVecEnv(experiment, names, session=session)
    try:
        vec.reset()
        actions = np.zeros((len(names), 1), dtype=np.float32)
        for _ in range(50):
            vec.step(actions)
        t = time.perf_counter()
        for _ in range(steps):
            vec.step(actions)
        return steps * len(names) / (time.perf_counter() - t)
    finally:
        vec.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--nodes", default="1,2,4")
    parser.add_argument("--port", type=int, default=17700)
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{args.port}"
    experiment = example_experiment("cartpole_continuous")
    session = open_session(ZenohOptions(listen=(endpoint,)))
    counts = [int(n) for n in args.nodes.split(",")]
    processes = [start([sys.executable, "-c", ECHO.replace("{endpoint}", endpoint)], "ready")]
    processes += [start_node(experiment, f"bench{i}", endpoint) for i in range(max(counts))]
    try:
        payload = len(proto.encode_values(proto.OUTPUTS, 1, 1, 0, np.zeros(4)))
        cpu = {"client": os.getpid(), "node": processes[1].pid}
        rows = []
        for name, samples in (
            (f"bare Zenoh ping-pong ({payload} B)", ping_pong(session, payload, args.steps)),
            (
                "RemoteFmuEnv.step",
                env_latency(RemoteFmuEnv(experiment, "bench0", session=session), args.steps, cpu),
            ),
            ("FmuEnv.step (in-process)", env_latency(FmuEnv(experiment), args.steps)),
        ):
            rows.append((name, *(f"{v:.0f}" for v in percentiles(samples))))
        print(f"loopback, {args.steps} samples each, cartpole_continuous\n")
        print(table(rows, ("per-sample latency", "median [us]", "p99 [us]")))
        ratio = float(rows[1][1]) / float(rows[0][1])
        print(f"\nremote step / bare ping-pong (median): {ratio:.2f}  (target <= 2)")
        if cpu["client_slices"]:  # resets included (one per episode, about 1 in 40 steps)
            print(
                "RemoteFmuEnv.step CPU time per step (all threads): "
                + ", ".join(
                    f"{who} {cpu[who + '_ns'] / args.steps / 1e3:.0f} us "
                    f"({cpu[who + '_slices'] / args.steps:.1f} time slices)"
                    for who in ("client", "node")
                )
                + f"; load average {os.getloadavg()[0]:.1f}"
            )
        print()
        single = None
        vec_rows = []
        for n in counts:
            rate = vec_throughput(experiment, [f"bench{i}" for i in range(n)], session, args.steps // 2)
            single = single or rate
            vec_rows.append((str(n), f"{rate:,.0f}", f"{rate / single:.2f}"))
        print(table(vec_rows, ("nodes", "env steps/s", "vs 1 node")))
        print("\ntarget: 4 nodes >= 1.6x one node on 2 cores")
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            process.wait(timeout=10)
        session.close()


if __name__ == "__main__":
    main()
