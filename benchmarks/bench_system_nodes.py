"""The distributed half of bench_system.py: a macro step of N Jacobi components in N nodes.

N DC motors in a chain (``c_i.torque -> c_{i+1}.load_torque``: each motor loads the next; the
task drives ``c0.voltage``), each served by its own ``fmu-bridge system serve --component c_i``
process on loopback, against one bare Zenoh round trip to an echo process with the same payload
as a node's outputs frame (the target's reference), and, for scale, a bare fan-out round trip to
N echo processes at once (what N parallel nodes cost with no FMU and no protocol at all). The
same four nodes serve every N: a component's node experiment depends only on its own connected
inputs, which are the same in every chain.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchmarks.bench_remote import ECHO, ping_pong, start
from benchmarks.common import table
from bridge.experiment.config import load_experiment
from bridge.net import protocol as proto
from bridge.net.system_node import NodeComponents
from bridge.net.transport import ZenohOptions, open_session, wait_connected
from bridge.plant.system.plant import SystemPlant

H = 1e-3


def chain(directory: Path, n: int) -> Path:
    """An experiment file of ``n`` DC motors in a chain, each in its own node."""
    components = {
        f"c{i}": {"fmu": "example:dcmotor", "feedthrough": False, "node": f"bench-c{i}"} for i in range(n)
    }
    data = {
        "name": f"chain{n}",
        "model": {"step_size": H, "episode_duration": 1e4},
        "system": {
            "components": components,
            "connections": [f"c{i}.torque -> c{i + 1}.load_torque" for i in range(n - 1)],
        },
        "actions": {"inputs": ["c0.voltage"]},
        "observations": {"outputs": [f"c{n - 1}.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    path = directory / f"chain{n}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def macro_steps(plant: SystemPlant, steps: int) -> list[float]:
    """Seconds per macro step (the plant's sample is one macro step)."""
    plant.reset({}, [12.0])
    for _ in range(200):
        plant.step([12.0])
    samples = []
    for k in range(steps):
        if plant.terminated or k % 5000 == 4999:
            plant.reset({}, [12.0])
        t = time.perf_counter()
        plant.step([12.0])
        samples.append(time.perf_counter() - t)
    return samples


def distributed(counts: list[int], steps: int) -> None:
    endpoint = "tcp/127.0.0.1:17711"
    prefix = f"bench_{uuid.uuid4().hex[:8]}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    processes = []
    with tempfile.TemporaryDirectory() as tmp:
        served = chain(Path(tmp), max(counts))
        try:
            processes.append(start([sys.executable, "-c", ECHO.replace("{endpoint}", endpoint)], "ready"))
            for i in range(max(counts)):
                processes.append(start([sys.executable, "-c", _echo(endpoint, i)], "ready"))
            for i in range(max(counts)):
                cmd = [sys.executable, "-m", "bridge.cli", "system", "serve", str(served)]
                cmd += ["--component", f"c{i}", "--connect", endpoint, "--prefix", prefix]
                processes.append(start(cmd, "serving;"))
            wait_connected(session)
            rows = _measure(session, prefix, Path(tmp), counts, steps)
        finally:
            for process in processes:
                process.terminate()
            for process in processes:
                process.wait(timeout=20)
            session.close()
    print(table(rows, ("across nodes (loopback)", "median [us]", "p99 [us]", "x round trip")))
    worst = max(float(r[3]) for r in rows[1:])
    verdict = "met" if worst <= 2 else "NOT met"
    print(f"target: a macro step of N components <= 2x one bare round trip: {verdict}")


def _measure(
    session: Any, prefix: str, directory: Path, counts: list[int], steps: int
) -> list[tuple[str, ...]]:
    outputs = np.zeros(3)  # a dcmotor node's outputs: omega, current, torque
    payload = len(proto.encode_values(proto.OUTPUTS, 1, 1, 0, outputs))
    bare = _stats(ping_pong(session, payload, steps))
    rows = [(f"bare Zenoh round trip ({payload} B)", f"{bare[0]:.0f}", f"{bare[1]:.0f}", "1.00")]
    for n in counts:
        fan = _stats(fan_out(session, payload, n, steps))
        rows.append((f"bare fan-out round trip to {n} echo(s)", f"{fan[0]:.0f}", f"{fan[1]:.0f}",
                     f"{fan[0] / bare[0]:.2f}"))  # fmt: skip
    for n in counts:
        exp = load_experiment(chain(directory, n))
        remote = NodeComponents(session=session, prefix=prefix, timeout_s=30.0)
        with SystemPlant(exp, remote=remote) as plant:
            plant.bind(["c0.voltage"], [f"c{n - 1}.omega"])
            median, p99 = _stats(macro_steps(plant, steps))
        rows.append(
            (f"macro step, {n} Jacobi node(s)", f"{median:.0f}", f"{p99:.0f}", f"{median / bare[0]:.2f}")
        )
    return rows


def _echo(endpoint: str, i: int) -> str:
    return (
        ECHO.replace("{endpoint}", endpoint)
        .replace("bench/p", f"fan{i}/p")
        .replace("bench/echo", f"fan{i}/e")
    )


def fan_out(session: Any, payload_size: int, n: int, steps: int) -> list[float]:
    """Seconds per round trip to ``n`` echo processes at once (put to all, wait for all)."""
    events = [threading.Event() for _ in range(n)]
    subs = [session.declare_subscriber(f"fan{i}/pong", lambda _s, e=e: e.set()) for i, e in enumerate(events)]
    pubs = [session.declare_publisher(f"fan{i}/ping") for i in range(n)]
    payload, samples = bytes(payload_size), []
    for k in range(steps + 200):
        for e in events:
            e.clear()
        t = time.perf_counter()
        for pub in pubs:
            pub.put(payload)
        if not all(e.wait(2.0) for e in events):
            raise RuntimeError("an echo was lost")
        if k >= 200:
            samples.append(time.perf_counter() - t)
    for entity in (*subs, *pubs):
        entity.undeclare()
    return samples


def _stats(samples: list[float]) -> tuple[float, float]:
    ordered = sorted(samples)
    return statistics.median(ordered) * 1e6, ordered[int(0.99 * (len(ordered) - 1))] * 1e6
