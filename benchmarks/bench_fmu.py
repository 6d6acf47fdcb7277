"""bridge.fmu stepping vs a raw FMPy loop on the same FMU, and the cost of each reset policy.

Run: python benchmarks/bench_fmu.py [--steps N] [--repeats R]
Prints medians of interleaved repetitions; the ratio is cost(bridge) / cost(raw FMPy).
"""

from __future__ import annotations

import argparse
import statistics
import time

from common import RawFmpyLoop, fmt_us, interleaved, table

from bridge.fmu import Model
from bridge.models import example_fmu

OUTPUTS = ["x", "x_dot", "theta", "theta_dot"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--resets", type=int, default=2_000)
    args = parser.parse_args()
    path = example_fmu("cartpole", "2.0", "cs")

    raw = RawFmpyLoop(path, ["force"], OUTPUTS, 0.02)
    model = Model(path, step_size_s=0.02)
    model.initialize()
    inputs = model.signals(["force"], writable=True)
    outputs = model.signals(OUTPUTS)

    def ours(steps: int) -> None:
        u = [0.5]
        for _ in range(steps):
            inputs.write(u)
            model.advance(1)
            y = outputs.read()
            if abs(y[0]) > 1e6:
                break

    def theirs(steps: int) -> None:
        raw.run(steps)

    def rewind(steps: int) -> None:  # keep both far from numerical blow-up
        model.reset()
        raw.reset()

    rates = interleaved({"raw FMPy loop": theirs, "bridge.fmu": ours}, args.steps, args.repeats)
    ratio = rates["raw FMPy loop"] / rates["bridge.fmu"]
    rows = [(name, f"{rate:,.0f}", fmt_us(rate)) for name, rate in rates.items()]
    print(f"FMU: {path.name} (FMI 2.0 CS), {args.steps} steps x {args.repeats} repeats, interleaved\n")
    print(table(rows, ("loop", "samples/s (median)", "us/sample")))
    print(f"\ncost ratio bridge.fmu / raw FMPy: {ratio:.3f}  (target <= 1.1)\n")
    raw.close()

    reset_rows = []
    for policy in ("restore", "reset", "reinstantiate"):
        with Model(path, step_size_s=0.02, reset_policy=policy) as m:  # type: ignore[arg-type]
            m.initialize({"theta0": 0.05})
            m.reset({"theta0": 0.05})  # restore takes its snapshot here
            samples = []
            for _ in range(5):
                start = time.perf_counter()
                for _ in range(args.resets):
                    m.reset({"theta0": 0.05})
                samples.append((time.perf_counter() - start) / args.resets)
            reset_rows.append((policy, f"{statistics.median(samples) * 1e6:.1f}"))
    print(table(reset_rows, ("reset policy", "us/reset (median)")))
    print("\ntarget: fmi reset or state restore <= 50 us on the example models")
    model.close()
    del rewind


if __name__ == "__main__":
    main()
