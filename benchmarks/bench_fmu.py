"""bridge.fmu stepping vs a raw FMPy loop on the same FMU, and the cost of each reset policy.

Run: python benchmarks/bench_fmu.py [--steps N] [--repeats R] [--only state]
Prints medians of interleaved repetitions; the ratio is cost(bridge) / cost(raw FMPy). The last
table puts a start from a state file beside a full initialisation on the slow-initialisation model
(``slow_init``, whose initialisation runs ``warmup_steps`` pseudo-time steps).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from common import RawFmpyLoop, fmt_us, interleaved, table

from bridge.fmu import Model, state_file
from bridge.models import example_fmu

OUTPUTS = ["x", "x_dot", "theta", "theta_dot"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--resets", type=int, default=2_000)
    parser.add_argument("--only", choices=("state",), help="only the state-file table")
    args = parser.parse_args()
    if args.only != "state":
        stepping_and_resets(args)
    state_files(args.repeats)


def stepping_and_resets(args: argparse.Namespace) -> None:
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


def state_files(repeats: int) -> None:
    """A fresh instance started by initialisation vs from a state file, and a reset by fmi reset
    plus initialisation vs a reset to the state file's state, on ``slow_init`` (FMI 2.0 CS)."""
    path = example_fmu("slow_init", "2.0", "cs")
    with tempfile.TemporaryDirectory() as tmp:
        saved = Path(tmp) / "slow_init.state"
        with Model(path) as m:
            m.initialize()
            state_file.write(saved, m.state_file())

        def open_initialise() -> None:
            with Model(path) as m:
                m.initialize()

        def open_from_file() -> None:
            with Model(path) as m:
                m.start_from(state_file.read(saved))
                m.reset()

        init_model, file_model = Model(path, reset_policy="reset"), Model(path)
        init_model.initialize()
        file_model.start_from(state_file.read(saved))
        file_model.reset()
        cases = {
            "new instance, full initialisation": open_initialise,
            "new instance, from the state file": open_from_file,
            "reset: fmi reset + initialisation": init_model.reset,
            "reset: to the state file's state": file_model.reset,
        }
        times: dict[str, list[float]] = {name: [] for name in cases}
        for _ in range(repeats):  # interleaved: load drifts hit every case alike
            for name, case in cases.items():
                start = time.perf_counter()
                case()
                times[name].append(time.perf_counter() - start)
        init_model.close()
        file_model.close()
    medians = {name: statistics.median(t) for name, t in times.items()}
    names = list(medians)
    rows = [(n, f"{medians[n] * 1e3:.3f}") for n in names]
    print(f"\nstate files on {path.name} (FMI 2.0 CS), {repeats} interleaved repeats\n")
    print(table(rows, ("start", "ms (median)")))
    for full, fast in ((names[0], names[1]), (names[2], names[3])):
        print(f"{fast!r} is {medians[full] / medians[fast]:,.0f}x faster than {full!r}")


if __name__ == "__main__":
    main()
