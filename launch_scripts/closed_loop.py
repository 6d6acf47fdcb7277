"""Closed loop without ROS: an FMU node in real time, a deployed agent and a recorder.

Run:  python launch_scripts/closed_loop.py RUN_DIR [--experiment FILE] [--rate 2] [--duration 20]
          [--transport zenoh|ros2] [--record out.mcap] [--port 7447]

This process is the Zenoh router (127.0.0.1); the node, the agent and the recorder are
subprocesses connecting to it, exactly as they would on separate machines. Ctrl-C stops all
three; the recording is finished properly.

Order matters for an honest recording: the recorder starts first, so the plant's samples from
its t = 0 on are in the file (the node publishes from its start, before the agent has loaded);
when the agent ends, the node is stopped before the recorder, so the file ends with the agent's
last action instead of showing the plant running on (the pole falling) with no agent.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from bridge.net.transport import ZenohOptions, open_session


def spawn(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *args], env={**os.environ, "PYTHONUNBUFFERED": "1"}
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run", type=Path, help="a run directory (or model .zip) from fmu-bridge train")
    parser.add_argument("--experiment", type=Path, help="default: the run's experiment.yaml")
    parser.add_argument("--node", default="plant")
    parser.add_argument("--rate", type=float, default=1.0, help="real-time factor of the node")
    parser.add_argument("--duration", type=float, default=20.0, help="wall-clock seconds")
    parser.add_argument("--transport", default="zenoh", choices=["zenoh", "ros2"])
    parser.add_argument("--record", type=Path, default=Path("recordings/closed_loop.mcap"))
    parser.add_argument("--port", type=int, default=7447)
    args = parser.parse_args()

    run_dir = args.run if args.run.is_dir() else args.run.parent
    experiment = args.experiment or run_dir / "experiment.yaml"
    endpoint = f"tcp/127.0.0.1:{args.port}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    args.record.parent.mkdir(parents=True, exist_ok=True)
    recorder = spawn("record", "--node", args.node, "-o", str(args.record), "--connect", endpoint)
    time.sleep(2.0)  # the recorder imports and subscribes before the node publishes its first sample
    node = spawn(
        "node",
        str(experiment),
        "--name",
        args.node,
        "--mode",
        "realtime",
        "--rate",
        str(args.rate),
        "--connect",
        endpoint,
        *(["--ros"] if args.transport == "ros2" else []),
    )
    processes = [recorder, node]
    try:
        time.sleep(3.0)  # the node imports and opens its FMU
        processes.append(
            spawn(
                "agent",
                "run",
                str(args.run),
                "--config",
                str(experiment),
                "--node",
                args.node,
                "--transport",
                args.transport,
                "--connect",
                endpoint,
                "--duration",
                str(args.duration),
            )
        )
        processes[-1].wait(timeout=args.duration + 120)
    except KeyboardInterrupt:
        pass
    finally:
        for process in reversed(processes):  # agent, node, then recorder: nothing after the agent
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
        session.close()
    print(f"recording: {args.record}")


if __name__ == "__main__":
    main()
