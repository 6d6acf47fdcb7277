"""Per-observation inference latency of a deployed policy: torch vs onnxruntime vs policy FMU.

    PYTHONPATH=$PWD python benchmarks/bench_deploy.py [RUN_DIR] [--n 5000]
    PYTHONPATH=$PWD python benchmarks/bench_deploy.py [RUN_DIR] --closed-loop [--samples 500]

``--closed-loop``: observation-to-action latency of ``fmu-bridge agent run`` closing the loop with
a real-time FMU node (50 Hz, both subprocesses), seen by a third participant that receives both
the node's outputs and the agent's actions: over DDS (rclpy, Fast DDS: the ``ros`` extra), over
the rmw_zenoh view (``--transport ros2``) and over native Zenoh frames, for torch, ONNX and the
policy FMU (``--runtime fmu``), one after the other in one run.

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


TRANSPORTS = {  # agent --transport, node flags
    "DDS (rclpy, Fast DDS)": ("rclpy", ["--ros-backend", "rclpy"]),
    "rmw_zenoh view": ("ros2", ["--ros", "--ros-backend", "zenoh"]),
    "native Zenoh": ("zenoh", []),
}


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _wait_line(process: Any, text: str, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            raise RuntimeError(f"{process.args} exited before printing {text!r}")
        if text in " ".join(line.split()):
            return
    raise RuntimeError(f"{process.args} did not print {text!r} in {timeout_s} s")


def _drain(process: Any) -> None:
    import threading

    threading.Thread(target=process.stdout.read, daemon=True).start()


def closed_loop(  # noqa: PLR0915
    run: Path, experiment: Path, transport: str, runtime: str, samples: int
) -> tuple[float, float]:
    """Observation-to-action latency (p50, p99 in us) of one agent against one real-time node."""
    import subprocess
    import sys
    import threading

    from bridge.net import protocol as proto
    from bridge.net.ros2 import cdr
    from bridge.net.ros2.view import RosViewSettings, open_backend_node
    from bridge.net.transport import ZenohOptions, open_session

    agent_transport, node_flags = TRANSPORTS[transport]
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    base = [sys.executable, "-m", "bridge.cli"]
    common = ["--connect", endpoint, "--prefix", "bench"]
    node = subprocess.Popen(
        [*base, "node", str(experiment), "--name", "plant", "--mode", "realtime", *common, *node_flags],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    agent = None
    seen: dict[object, float] = {}
    latencies: list[float] = []
    lock = threading.Lock()

    def output(key: object) -> None:
        with lock:
            seen[key] = time.perf_counter()

    def action(key: object) -> None:
        now = time.perf_counter()
        with lock:
            sent = seen.pop(key, None)
            if sent is not None:
                latencies.append(now - sent)

    watcher: Any = None
    subscribers: list[Any] = []
    try:
        _wait_line(node, "serving")
        _drain(node)
        if agent_transport == "zenoh":
            keys = proto.Keys("bench", "plant")

            def on_output(sample: Any) -> None:
                frame = proto.decode(sample.payload.to_bytes())
                output((frame.episode, frame.step + 1))  # the agent answers step k with step k + 1

            def on_action(sample: Any) -> None:
                frame = proto.decode(sample.payload.to_bytes())
                action((frame.episode, frame.step))

            subscribers = [
                router.declare_subscriber(keys.outputs, on_output),
                router.declare_subscriber(keys.actions, on_action),
            ]
        else:  # actions are stamped with the observation they answer
            backend = "rclpy" if agent_transport == "rclpy" else "zenoh"
            watcher = open_backend_node(router, RosViewSettings(backend=backend), "bench_watcher")
            watcher.create_subscription(
                "/plant/outputs", "sensor_msgs/msg/JointState",
                lambda payload, info: output(cdr.decode_joint_state(payload).stamp_ns),
            )  # fmt: skip
            watcher.create_subscription(
                "/plant/actions", "sensor_msgs/msg/JointState",
                lambda payload, info: action(cdr.decode_joint_state(payload).stamp_ns),
            )  # fmt: skip
        agent = subprocess.Popen(
            [*base, "agent", "run", str(run), "--config", str(experiment), "--node", "plant",
             "--transport", agent_transport, "--runtime", runtime, *common],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        _wait_line(agent, "Ctrl-C stops it")
        _drain(agent)
        deadline = time.monotonic() + samples / 50 * 4 + 30
        while time.monotonic() < deadline:
            with lock:
                if len(latencies) >= samples + 50:
                    break
            time.sleep(0.1)
        with lock:
            measured = np.asarray(latencies[50:])  # after the first second: warm
    finally:
        for process in (agent, node):
            if process is not None:
                process.terminate()
                process.wait(timeout=30)
        for subscriber in subscribers:
            subscriber.undeclare()
        if watcher is not None:
            watcher.close()
        router.close()
    if len(measured) == 0:
        raise RuntimeError(f"no closed-loop sample over {transport} ({runtime})")
    return float(np.median(measured)) * 1e6, float(np.quantile(measured, 0.99)) * 1e6


def endless(source: Path, folder: Path) -> Path:
    """The experiment without termination, 1000 s long: the loop runs whatever the policy does."""
    import yaml

    data = yaml.safe_load(source.read_text())
    data["model"]["episode_duration"] = 1000.0
    data.pop("termination", None)
    path = folder / "endless.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def main_closed_loop(run: Path, tmp: Path, samples: int) -> None:
    from agents.export.onnx import export_onnx
    from agents.export.policy_fmu import export_fmu

    if not (run / "policy.onnx").is_file():
        export_onnx(run)
    if not (run / "policy-fmi2.fmu").is_file():
        export_fmu(run, "2")
    experiment = endless(Path("examples/cartpole_continuous.yaml"), tmp)
    rows = {}
    for transport in TRANSPORTS:
        for runtime in ("torch", "onnx", "fmu"):
            rows[(transport, runtime)] = closed_loop(run, experiment, transport, runtime, samples)
    print(
        f"{'transport':24s} {'runtime':8s} {'p50 [us]':>10s} {'p99 [us]':>10s}   ({samples} samples at 50 Hz)"
    )
    for (transport, runtime), (p50, p99) in rows.items():
        print(f"{transport:24s} {runtime:8s} {p50:10.0f} {p99:10.0f}")


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
    parser.add_argument(
        "--closed-loop", action="store_true", help="agent and node over DDS, rmw_zenoh, Zenoh"
    )
    parser.add_argument("--samples", type=int, default=500)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.closed_loop:
        with tempfile.TemporaryDirectory() as tmp:
            main_closed_loop(args.run or tiny_run(Path(tmp)), Path(tmp), args.samples)
        return
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
