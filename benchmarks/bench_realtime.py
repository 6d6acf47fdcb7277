"""The real-time driver's period as a subscriber on the same machine sees it.

Run: python benchmarks/bench_realtime.py [--seconds 10] [--rate 20] [--modes sleep,hybrid,fifo]

A real-time node serves the cart-pole (sampling time 20 ms) at ``--rate 20``: one sample every
1 ms. The node runs in its own process; this process subscribes to its outputs key and stamps
every frame on arrival (``time.monotonic_ns`` in the Zenoh callback). Reported per pacing mode:
the median interval between frames, and the absolute deviation of the intervals from the
nominal period at p99, p99.9 and its maximum, with the node's overrun count.

Modes (``bridge.net.realtime.Pacing``): ``sleep`` sleeps to each deadline (no busy tail, the
pacing of the first release), ``hybrid`` sleeps to 300 us before it and waits out the rest in a
short clock-reading loop (the default), ``fifo`` is hybrid with SCHED_FIFO 50 for the driver's
thread where the process may ask for it (the table says whether it was granted), and SCHED_FIFO 49
for the Zenoh threads of the node and of the subscriber (a priority only root or CAP_SYS_NICE
gets; on a busy machine the frame waits in normal-priority threads otherwise).

Target on a quiet machine: |deviation| p99 <= 50 us, max <= 500 us without root.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import statistics
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

from common import table

from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session, wait_connected

NODE = """
import os, sys, threading
from bridge.net.node import FmuNode
from bridge.net.realtime import Pacing
from bridge.net.transport import ZenohOptions

experiment, name, endpoint, prefix, rate, spin_us, priority = sys.argv[1:]
pacing = Pacing(spin_s=float(spin_us) * 1e-6, priority=int(priority) if priority != "-" else None)
if priority != "-":  # Zenoh's threads, started by the session below, inherit it
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority) - 1))
    except OSError:
        pass
node = FmuNode(experiment, name=name, mode="realtime", rate=float(rate), prefix=prefix,
               options=ZenohOptions(connect=(endpoint,)), pacing=pacing)
threading.Event().wait(0.5)
print("serving", node._driver.scheduling, node.counters["overruns"], flush=True)
sys.stdin.readline()
print("overruns", node.counters["overruns"], flush=True)
node.close()
"""
MODES = {"sleep": ("0", "-"), "hybrid": ("300", "-"), "fifo": ("300", "50")}


def measure(
    experiment: Path, endpoint: str, session: object, mode: str, *, rate: float, seconds: float
) -> tuple[str, ...]:
    priority = MODES[mode][1]
    if priority != "-":  # the subscriber's Zenoh threads too, where allowed: a session of its own
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority) - 1))
        fifo_session = open_session(ZenohOptions(connect=(endpoint,)))
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        try:
            return _measure(experiment, endpoint, fifo_session, mode, rate=rate, seconds=seconds)
        finally:
            fifo_session.close()  # type: ignore[attr-defined]
    return _measure(experiment, endpoint, session, mode, rate=rate, seconds=seconds)


def _measure(
    experiment: Path, endpoint: str, session: object, mode: str, *, rate: float, seconds: float
) -> tuple[str, ...]:
    spin_us, priority = MODES[mode]
    prefix, name = f"rt_{uuid.uuid4().hex[:8]}", "rt"
    stamps: list[int] = []
    done = threading.Event()

    def on_frame(_sample: object) -> None:
        stamps.append(time.monotonic_ns())

    keys = proto.Keys(prefix, name)
    sub = session.declare_subscriber(keys.outputs, on_frame)  # type: ignore[attr-defined]
    cmd = [sys.executable, "-c", NODE, str(experiment), name, endpoint, prefix, str(rate), spin_us, priority]
    node = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    assert node.stdout is not None and node.stdin is not None
    try:
        line = node.stdout.readline().split()
        if not line or line[0] != "serving":
            raise RuntimeError(f"the real-time node did not start ({line})")
        scheduling = " ".join(line[1:-1])
        time.sleep(1.0)  # warm-up: connections settle
        start = len(stamps)
        done.wait(seconds)
        end = len(stamps)
        node.stdin.write("\n")
        node.stdin.flush()
        overruns = node.stdout.readline().split()[-1]
    finally:
        node.stdin.close()
        node.wait(timeout=20)
        sub.undeclare()
    window = stamps[start:end]
    period_ns = 0.02 / rate * 1e9
    intervals = [b - a for a, b in itertools.pairwise(window)]
    deviations = sorted(abs(i - period_ns) for i in intervals)

    def at(q: float) -> float:
        return deviations[min(len(deviations) - 1, int(q * len(deviations)))] / 1e3

    return (
        mode,
        scheduling,
        str(len(intervals)),
        f"{statistics.median(intervals) / 1e3:.1f}",
        f"{at(0.99):.0f}",
        f"{at(0.999):.0f}",
        f"{deviations[-1] / 1e3:.0f}",
        overruns,
    )


def driver_alone(mode: str, seconds: float, period_s: float) -> tuple[str, ...]:
    """The driver's own ticks in this process (no FMU, no Zenoh, no subscriber): its pacing alone."""
    from collections import Counter

    from bridge.net.realtime import Pacing, RealtimeDriver

    spin_us, priority = MODES[mode]
    stamps: list[int] = []

    def tick() -> bool:
        stamps.append(time.monotonic_ns())
        return True

    counters: Counter[str] = Counter()
    pacing = Pacing(spin_s=float(spin_us) * 1e-6, priority=int(priority) if priority != "-" else None)
    driver = RealtimeDriver(tick, period_s, name="alone", counters=counters, pacing=pacing)
    driver.start()
    time.sleep(seconds)
    driver.stop()
    intervals = [b - a for a, b in itertools.pairwise(stamps[100:])]
    deviations = sorted(abs(i - period_s * 1e9) for i in intervals)

    def at(q: float) -> float:
        return deviations[min(len(deviations) - 1, int(q * len(deviations)))] / 1e3

    return (
        mode,
        driver.scheduling,
        str(len(intervals)),
        f"{statistics.median(intervals) / 1e3:.1f}",
        f"{at(0.99):.0f}",
        f"{at(0.999):.0f}",
        f"{deviations[-1] / 1e3:.0f}",
        str(counters["overruns"]),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=20.0)
    parser.add_argument("--modes", default="sleep,hybrid,fifo")
    parser.add_argument("--port", type=int, default=17741)
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{args.port}"
    experiment = example_experiment("cartpole_continuous")
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    try:
        rows = []
        for mode in args.modes.split(","):
            rows.append(measure(experiment, endpoint, session, mode, rate=args.rate, seconds=args.seconds))
            wait_connected(session, timeout_s=0.1)
    finally:
        session.close()  # type: ignore[attr-defined]
    period_us = 0.02 / args.rate * 1e6
    load = os.getloadavg()[0]
    print(f"cart-pole real-time node at --rate {args.rate:g} (period {period_us:.0f} us), {args.seconds:g} s "
          f"per mode, load average {load:.1f} on {os.cpu_count()} CPUs\n")  # fmt: skip
    header = ("pacing", "scheduling", "intervals", "median [us]", "|dev| p99 [us]", "p99.9 [us]", "max [us]",
              "overruns")  # fmt: skip
    print(table(rows, header))
    alone = [driver_alone(mode, args.seconds / 2, 0.02 / args.rate) for mode in args.modes.split(",")]
    print("\nthe driver alone, in this process (a tick that only reads the clock):\n")
    print(table(alone, header))
    print("\ntarget on a quiet machine: |deviation| p99 <= 50 us, max <= 500 us, without root")


if __name__ == "__main__":
    main()
