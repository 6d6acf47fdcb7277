"""What a sample costs when the FMU's clocks tick: clocks3 in each FMI 3.0 interface, one run.

Run: python benchmarks/bench_clocks.py [--samples N] [--repeats R]

One sample is 0.25 s of clocks3 (``models/clocks3/clocks3.c``): about 7.6 clock ticks, so the FMU
step is split into several pieces with an event (co-simulation, model exchange) or a model-partition
activation (scheduled execution) at each. Medians of interleaved repeats, CPU time of this thread.
For reference, the feedthrough example (FMI 3.0 co-simulation, no clocks: one doStep per sample)
through the same ``Model.advance``. The machine may be loaded: compare rows of one run only.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from common import interleaved, table

from bridge.fmu import Model
from bridge.models import example_fmu
from bridge.models.clocked import clocks_fmu

EPISODE = 12  # samples of 0.25 s: the 3 s over which clocks3's ticks are known in closed form


def _loop(model: Model) -> Callable[[int], None]:
    def run(samples: int) -> None:
        done = 0
        while done < samples:
            model.reset()
            for _ in range(min(EPISODE, samples - done)):
                model.advance(1)
            done += EPISODE

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=600)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    models = {
        "clocks3 co-simulation (event mode)": Model(clocks_fmu("cs"), step_size_s=0.25),
        "clocks3 scheduled execution": Model(clocks_fmu("se"), step_size_s=0.25),
        "clocks3 model exchange, rk4 x10": Model(
            clocks_fmu("me"), step_size_s=0.25, solver="rk4", solver_substeps=10
        ),
        "clocks3 model exchange, CVode": Model(clocks_fmu("me"), step_size_s=0.25),
        "feedthrough 3.0 CS, no clocks": Model(example_fmu("feedthrough", "3.0", "cs"), step_size_s=0.25),
    }
    try:
        rates = interleaved(
            {name: _loop(m) for name, m in models.items()}, args.samples, args.repeats, clock=time.thread_time
        )
    finally:
        for m in models.values():
            m.close()
    rows: list[tuple[str, ...]] = [
        (name, f"{rate:,.0f}", f"{1e6 / rate:.1f}") for name, rate in rates.items()
    ]
    print(f"{args.samples} samples x {args.repeats} repeats, interleaved, CPU time (resets included)\n")
    print(table(rows, ("model", "samples/s (median)", "us/sample")))


if __name__ == "__main__":
    main()
