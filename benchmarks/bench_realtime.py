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

Two floors are measured beside the node with the same subscriber and the same ``hybrid`` pacing,
so that what the node adds can be told from what the machine and the transport cost:
``floor zenoh`` is a bare process that only publishes a frame of the node's size on a Zenoh key
from the same driver (no FMU, no node), and ``floor pipe`` a bare process that writes the frame to
an OS pipe that a thread here reads (no Zenoh: the cost of waking another process's thread).

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
from bridge.net.realtime import Pacing
from bridge.serving import experiment_node
from bridge.net.transport import ZenohOptions

experiment, name, endpoint, prefix, rate, spin_us, priority = sys.argv[1:]
pacing = Pacing(spin_s=float(spin_us) * 1e-6, priority=int(priority) if priority != "-" else None)
if priority != "-":  # Zenoh's threads, started by the session below, inherit it
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority) - 1))
    except OSError:
        pass
node = experiment_node(experiment, name=name, mode="realtime", rate=float(rate), prefix=prefix,
                       options=ZenohOptions(connect=(endpoint,)), pacing=pacing)
threading.Event().wait(0.5)
print("serving", node._driver.scheduling, node.counters["overruns"], flush=True)
sys.stdin.readline()
print("overruns", node.counters["overruns"], flush=True)
node.close()
"""
FLOOR = """
import os, sys, threading
from collections import Counter
from bridge.net.realtime import Pacing, RealtimeDriver

kind, period_s, target, size = sys.argv[1], float(sys.argv[2]), sys.argv[3], int(sys.argv[4])
payload = bytes(size)
if kind == "zenoh":
    from bridge.net.transport import ZenohOptions, open_session
    session = open_session(ZenohOptions(connect=(target,)))
    publisher = session.declare_publisher(sys.argv[5])
    send = lambda: publisher.put(payload)
else:
    fd = int(target)
    send = lambda: os.write(fd, payload)

def tick():
    send()
    return True

counters = Counter()
driver = RealtimeDriver(tick, period_s, name="floor", counters=counters, pacing=Pacing())
driver.start()
print("serving", driver.scheduling, flush=True)
sys.stdin.readline()
driver.stop()
print("overruns", counters["overruns"], flush=True)
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
    return _row(mode, scheduling, stamps[start:end], 0.02 / rate * 1e9, overruns)


def _row(label: str, scheduling: str, stamps: list[int], period_ns: float, overruns: str) -> tuple[str, ...]:
    intervals = [b - a for a, b in itertools.pairwise(stamps)]
    deviations = sorted(abs(i - period_ns) for i in intervals)

    def at(q: float) -> float:
        return deviations[min(len(deviations) - 1, int(q * len(deviations)))] / 1e3

    return (
        label,
        scheduling,
        str(len(intervals)),
        f"{statistics.median(intervals) / 1e3:.1f}",
        f"{at(0.99):.0f}",
        f"{at(0.999):.0f}",
        f"{deviations[-1] / 1e3:.0f}",
        overruns,
    )


def floor(kind: str, endpoint: str, session: object, *, rate: float, seconds: float) -> tuple[str, ...]:
    """A bare process publishing a node-sized frame from the same driver and pacing (``zenoh``:
    on a Zenoh key this process subscribes to; ``pipe``: into an OS pipe a thread here reads)."""
    period_s = 0.02 / rate
    size = 32 + 8 * 4  # header, count and the cart-pole's four outputs
    stamps: list[int] = []
    extra: list[str] = []
    sub = None
    reader = None
    pass_fds: tuple[int, ...] = ()
    if kind == "zenoh":
        key = f"rt_floor_{uuid.uuid4().hex[:8]}"
        sub = session.declare_subscriber(key, lambda _sample: stamps.append(time.monotonic_ns()))  # type: ignore[attr-defined]
        target, extra = endpoint, [key]
    else:
        read_fd, write_fd = os.pipe()
        target, pass_fds = str(write_fd), (write_fd,)

        def read() -> None:
            while os.read(read_fd, size):
                stamps.append(time.monotonic_ns())

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
    cmd = [sys.executable, "-c", FLOOR, kind, repr(period_s), target, str(size), *extra]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, pass_fds=pass_fds)
    for fd in pass_fds:  # the child's now: the reader sees the end of the pipe when the child exits
        os.close(fd)
    assert proc.stdout is not None and proc.stdin is not None
    try:
        line = proc.stdout.readline().split()
        if not line or line[0] != "serving":
            raise RuntimeError(f"the floor process did not start ({line})")
        time.sleep(1.0)  # warm-up, as for the node
        start = len(stamps)
        threading.Event().wait(seconds)
        end = len(stamps)
        proc.stdin.write("\n")
        proc.stdin.flush()
        overruns = proc.stdout.readline().split()[-1]
    finally:
        proc.stdin.close()
        proc.wait(timeout=20)
        if sub is not None:
            sub.undeclare()
        if reader is not None:
            reader.join(timeout=5)
            os.close(read_fd)
    return _row(f"floor {kind}", " ".join(line[1:]), stamps[start:end], period_s * 1e9, overruns)


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
    return _row(mode, driver.scheduling, stamps[100:], period_s * 1e9, str(counters["overruns"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=20.0)
    parser.add_argument("--modes", default="sleep,hybrid,fifo")
    parser.add_argument("--port", type=int, default=17741)
    parser.add_argument("--no-floors", action="store_true", help="skip the bare Zenoh and pipe floors")
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{args.port}"
    experiment = example_experiment("cartpole_continuous")
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    try:
        rows = []
        for mode in args.modes.split(","):
            rows.append(measure(experiment, endpoint, session, mode, rate=args.rate, seconds=args.seconds))
            wait_connected(session, timeout_s=0.1)
        if not args.no_floors:
            for kind in ("zenoh", "pipe"):
                rows.append(floor(kind, endpoint, session, rate=args.rate, seconds=args.seconds))
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
